"""Bus transports, chosen by a URL as python-can chooses interfaces.

    smbus:1              /dev/i2c-1 through smbus2 (also smbus:/dev/i2c-3)
    blinka:              Adafruit Blinka busio.I2C (any Blinka board or USB I2C adapter)
    serial:/dev/ttyACM0  a USB MicroPython board running the HIL bridge (or the simulator's pty);
                         options ?baud=115200&timeout=0.1 (s per attempt)
    sim:                 the shared simulated arm (a background service, real time; see sim_service)
    sim:virtual          simulated joints in this process, in virtual time (tests, the demo)
    sim:realtime         simulated joints in this process, following the wall clock

Beside the `bus` package, not in it: the `sim:` transport is the simulated arm's service, which
is built on the bus interface (bus.base); each transport is imported only when opened.
"""

from __future__ import annotations

from typing import Any, Callable

from .bus.base import Bus
from .errors import ConfigError

__all__ = ["open_bus", "register_transport", "schemes", "TRANSPORTS"]


def _smbus(target: str, **kwargs: Any) -> Bus:
    from .bus.smbus import SMBusBus
    return SMBusBus(int(target) if target.isdigit() else (target or 1), **kwargs)


def _blinka(target: str, **kwargs: Any) -> Bus:
    from .bus.blinka import BlinkaBus
    return BlinkaBus(**kwargs)


def _serial(target: str, **kwargs: Any) -> Bus:
    from .bus.serial import SerialBus
    return SerialBus.from_target(target, **kwargs)


def _sim(target: str, **kwargs: Any) -> Bus:
    joints = kwargs.pop("sim_joints", None)
    if joints is None:
        raise ConfigError("sim: needs the arm configuration to know which joints to simulate")
    realtime = kwargs.pop("realtime", False)
    service = {"idle_exit_s": kwargs.pop("idle_exit_s")} if "idle_exit_s" in kwargs else {}
    if target == "":
        from .paths import default_state_dir
        from .sim_service import ServiceBus
        kwargs.pop("port", None)
        return ServiceBus(joints, kwargs.pop("state_dir", None) or default_state_dir(), **service, **kwargs)
    if target not in ("virtual", "realtime"):
        raise ConfigError(f"unknown simulator sim:{target}; use sim: (the shared arm), sim:virtual or sim:realtime")
    from .bus.sim import SimBus
    return SimBus(joints, realtime=realtime or target == "realtime", **kwargs)


TRANSPORTS: dict[str, Callable[..., Bus]] = {"smbus": _smbus, "blinka": _blinka, "serial": _serial,
                                             "sim": _sim}


def register_transport(scheme: str, factory: Callable[..., Bus]) -> None:
    TRANSPORTS[scheme] = factory


def schemes() -> tuple[str, ...]:
    """The URL prefixes a bus may have ("smbus:", ...)."""
    return tuple(f"{name}:" for name in TRANSPORTS)


def open_bus(url: str, **kwargs: Any) -> Bus:
    """Open the bus named by `url` (see the module docstring); kwargs go to the transport."""
    scheme, sep, target = url.partition(":")
    if not sep or scheme not in TRANSPORTS:
        known = ", ".join(f"{name}:" for name in TRANSPORTS)
        raise ConfigError(f"unknown bus {url!r}; use one of {known}")
    return TRANSPORTS[scheme](target, **kwargs)
