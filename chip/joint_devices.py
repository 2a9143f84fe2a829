"""Python side of the joint's device fakes (chip/src/joint-devices.mjs) on an EmulatedPico.

    pico = EmulatedPico(plugins=[JOINT_DEVICES_PLUGIN])
    devices = JointDevices(pico)
    devices.state()["driver"]["irun"]; devices.stops(low=-10.0)
"""

from __future__ import annotations

from typing import Any

from .board import EmulatedPico

JOINT_DEVICES_PLUGIN: dict[str, Any] = {"module": "src/joint-devices.mjs", "options": {"name": "joint"}}
USTEPS_PER_REV = 51200  # 1/256 full steps of a 200-step motor
COUNTS_PER_REV = 4096  # AS5600


class JointDevices:
    """The TMC2209, AS5600 and rotor of one emulated joint, through the harness control channel."""

    def __init__(self, pico: EmulatedPico, name: str = "joint") -> None:
        self.pico = pico
        self.name = name

    def _call(self, command: str, **args: Any) -> dict[str, Any]:
        reply = self.pico.request(f"{self.name}.{command}", **args)
        return {k: v for k, v in reply.items() if k not in ("id", "ok")}

    def state(self) -> dict[str, Any]:
        """driver (register file, ifcnt, writes, microsteps, ihold/irun, steps), rotor, encoder, bus."""
        return self._call("state")

    def stops(self, low: float | None = None, high: float | None = None) -> dict[str, Any]:
        """End stops in motor degrees from the rotor's present position (None: no stop)."""
        return self._call("stops", low=low, high=high)

    def driver_faults(self, **faults: Any) -> dict[str, Any]:
        """badCrc=n, silent=n, ignoreWrites=n (the next n datagrams), absent=bool, echo=bool."""
        return self._call("driver_faults", **faults)

    def encoder_faults(self, **faults: Any) -> dict[str, Any]:
        """nack=n (the next n transfers), absent=bool, noise=counts, magnet='ok'|'weak'|'strong'|'none'."""
        return self._call("encoder_faults", **faults)

    def capture_steps(self, on: bool) -> list[float]:
        """Start recording STEP times (on=True); on=False stops and returns them (emulated ns)."""
        return list(self._call("capture_steps", on=on).get("times", []))
