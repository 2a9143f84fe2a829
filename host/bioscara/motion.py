"""Arm-level motions built on read/write cycles: homing all joints, moving to joint targets.

They take a runner with `run_until(predicate, timeout)` that keeps the arm cycling (read, write)
until the predicate holds: the Communicator, in the calling thread or from its loop thread.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from typing import Protocol

from .arm import Arm, Lifecycle, Mode
from .errors import NotHomedError
from .joint import WaitTimeoutError


class Runner(Protocol):
    def run_until(self, predicate: Callable[[], bool], timeout: float) -> None: ...


def home(arm: Arm, runner: Runner, joints: Iterable[str] | None = None,
         directions: Mapping[str, int] | None = None, timeout: float = 300.0) -> None:
    """Home `joints` (default: all) toward their configured end stops, through the home interfaces.

    Mirrors the operator's flow in the original: activate the home command interface, trigger +/-1,
    wait until BUSY drops, release the interface (which re-enables the joint).
    """
    names = list(joints) if joints is not None else list(arm.joints)
    directions = {name: (directions or {}).get(name, arm[name].config.homing.direction) for name in names}
    active = [f"{name}/{mode.value}" for name in names for mode in arm[name].modes]
    arm.switch_modes(start=[f"{name}/home" for name in names], stop=active)
    try:
        for name in names:
            arm.set_command(name, "home", directions[name])
        runner.run_until(lambda: all(arm[n].command.home == 0.0 for n in names), timeout)
    except BaseException:
        for name in names:
            arm.set_command(name, "home", 0.0)
        if arm.lifecycle is Lifecycle.ACTIVE:
            arm.write()
        raise
    finally:
        if arm.lifecycle is Lifecycle.ACTIVE:
            arm.switch_modes(stop=[f"{name}/home" for name in names])
    missing = [name for name in names if arm[name].state.home != 1.0]
    if missing:
        # what ended it, as the joint said (its deadman, a stall, a reboot): the log is not where a user looks
        why = [f"{name} ({arm[name].joint.homing_failure})" if arm[name].joint.homing_failure else name
               for name in missing]
        raise NotHomedError(f"homing ended without reaching the end stop: {', '.join(why)}")


def move_to(arm: Arm, runner: Runner, targets: Mapping[str, float], tolerance: float = 1e-3,
            timeout: float = 60.0) -> dict[str, float]:
    """Position-mode move of the joints in `targets`; returns the final measured positions."""
    for name in targets:
        if Mode.POSITION not in arm[name].modes:
            arm.switch_modes(start=[f"{name}/position"], stop=[f"{name}/{m.value}" for m in arm[name].modes])
    for name, target in targets.items():
        arm.set_command(name, "position", target)

    def arrived() -> bool:
        return all(abs(arm[n].state.position - t) <= tolerance and abs(arm[n].state.velocity) <= tolerance
                   for n, t in targets.items())
    try:
        runner.run_until(arrived, timeout)
    except WaitTimeoutError:
        where = ", ".join(f"{n} at {arm[n].state.position:.4f} (target {t:.4f})" for n, t in targets.items())
        raise WaitTimeoutError(f"move not finished after {timeout:g} s: {where}") from None
    return {name: arm[name].state.position for name in targets}


def positions(arm: Arm) -> dict[str, float]:
    return {name: aj.state.position for name, aj in arm.joints.items()}
