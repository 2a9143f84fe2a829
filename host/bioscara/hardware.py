"""Open what a configuration describes: the bus (simulated in mock mode), the arm, the gripper."""

from __future__ import annotations

from typing import Any, Callable

from .arm import Arm
from .bus import Bus, open_bus
from .bus.sim import SimJointSpec
from .config import ArmConfig
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


def open_arm(config: ArmConfig, bus: Bus | None = None, protocol: str = "auto") -> Arm:
    """The arm of `config`; `protocol` "auto" (v2 where the joints serve it), "legacy" or "v2"."""
    return Arm(config, bus if bus is not None else open_arm_bus(config), protocol)


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
