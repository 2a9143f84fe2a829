"""Open what a configuration describes: the bus (simulated in mock mode), the arm, the gripper.

`open_arm()` is the Python API's entry point; the command line opens the same way (session.py)."""

from __future__ import annotations

from typing import Any, Callable

from .arm import Arm
from .bus import Bus
from .transports import open_bus
from .bus.sim import SimJointSpec
from .config import ArmConfig, load_config
from .gripper import BaseGripper, Gripper, MockGripper


def sim_joint_specs(config: ArmConfig) -> list[SimJointSpec]:
    """The simulated joints for `config`: j1..j4 run firmware J1..J4, end stops at the joint limits."""
    return [SimJointSpec(name.upper(), jc.address, jc.reduction, jc.min, jc.max, config.sim.start[name],
                         payload_kg=config.sim.payload_kg, noise=config.sim.noise)
            for name, jc in config.joints.items()]


def open_arm_bus(config: ArmConfig, **overrides: Any) -> Bus:
    """The bus of `config` (`sim:` when use_mock_hardware); keyword overrides go to the transport."""
    kwargs: dict[str, Any] = {"attempts": config.bus.attempts, "speed_hz": config.bus.speed_hz}
    if config.bus_url.startswith("sim:"):
        kwargs.update(sim_joints=sim_joint_specs(config), seed=config.sim.seed, realtime=config.sim.realtime,
                      idle_exit_s=config.sim.idle_exit_min * 60.0 or None)
    kwargs.update(overrides)
    return open_bus(config.bus_url, **kwargs)


def open_arm(config: ArmConfig | None = None, bus: Bus | None = None, protocol: str = "auto", *,
             watch: bool = False, take_over: bool = False) -> Arm:
    """The arm a program uses, as the `bioscara` commands open it.

    `config`: by default `load_config()` (the user's file or the shipped one, $BIOSCARA_BUS);
    `bus`: by default the configuration's, opened here and closed with the arm; `protocol` "auto"
    (v2 where the joints serve it), "legacy" or "v2"; `watch`: only read, beside whatever program
    commands the arm; `take_over`: if another program commands it, stop that one and command.

        with open_arm() as arm:       # configured; on exit stopped, disabled and let go
            arm.activate()
            ...
    """
    config = config if config is not None else load_config()
    owns_bus = bus is None
    bus = bus if bus is not None else open_arm_bus(config)
    if take_over and bus.commander is not None:
        bus.commander.take_over = True
    arm = Arm(config, bus, protocol, watch=watch)
    arm.owns_bus = owns_bus
    return arm


def open_gripper(config: ArmConfig, clock: Callable[[], float] | None = None) -> BaseGripper | None:
    """The gripper of `config`, or None if it has none; a MockGripper in mock or simulated setups.

    `clock` (seconds) drives the gripper's position estimate; pass the bus clock in simulation.
    """
    if config.gripper is None:
        return None
    kwargs = {"clock": clock} if clock is not None else {}
    if config.gripper.use_mock or config.bus_url.startswith("sim:"):
        return MockGripper(config.gripper, **kwargs)
    return Gripper(config.gripper, **kwargs)
