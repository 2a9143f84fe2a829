"""The simulated arm demo: configure, activate, home every joint, pick and place, report."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

from rich.console import Console
from rich.table import Table

from . import interruption, motion, report
from .communicator import Communicator
from .config import ArmConfig, load_config
from .hardware import open_arm, open_gripper

# Joint targets (rad for j1, j3, j4; m for j2) and gripper widths (m) of a short pick and place.
PICK_AND_PLACE = (
    ("above pick", {"j1": 0.6, "j2": 0.25, "j3": -1.2, "j4": 0.6}, 0.10),
    ("at pick", {"j1": 0.6, "j2": 0.05, "j3": -1.2, "j4": 0.6}, 0.05),
    ("lift", {"j1": 0.6, "j2": 0.25, "j3": -1.2, "j4": 0.6}, 0.05),
    ("above place", {"j1": -0.8, "j2": 0.25, "j3": 1.0, "j4": -0.4}, 0.05),
    ("at place", {"j1": -0.8, "j2": 0.07, "j3": 1.0, "j4": -0.4}, 0.10),
    ("retreat", {"j1": 0.0, "j2": 0.30, "j3": 0.0, "j4": 0.0}, 0.08),
)
TOLERANCE = 2e-3


@dataclass
class Step:
    name: str
    targets: dict[str, float]
    reached: dict[str, float]
    gripper_target: float
    gripper: float


def run(config: ArmConfig | None = None, console: Console | None = None) -> list[Step]:
    console = console or Console()
    config = config or load_config()
    config = replace(config, bus=replace(config.bus, url="sim:", use_mock_hardware=True))
    wall0 = time.perf_counter()
    arm = open_arm(config)
    runner = Communicator(arm, frequency=100.0)
    gripper = open_gripper(config, clock=arm.bus.monotonic)
    steps: list[Step] = []
    try:
        arm.configure()
        arm.activate()
        console.print(f"[bold]arm active[/] on {arm.bus.describe()}, homing {', '.join(arm.joints)} ...")
        t = arm.bus.monotonic()
        motion.home(arm, runner)
        console.print(f"homed in {arm.bus.monotonic() - t:.1f} s (virtual)")
        if gripper is not None:
            gripper.init()
            gripper.enable()
        for name, targets, width in PICK_AND_PLACE:
            if gripper is not None:
                gripper.set_position(width)
            reached = motion.move_to(arm, runner, targets, tolerance=TOLERANCE, timeout=60.0)
            if gripper is not None:
                runner.run_until(lambda: gripper.get_velocity() == 0.0, timeout=5.0)
            steps.append(Step(name, targets, reached, width, gripper.get_position() if gripper else width))
            console.print(f"  {name}: done at t = {arm.bus.monotonic():.1f} s")
        arm.deactivate()
        if gripper is not None:
            gripper.disable()
    except KeyboardInterrupt:  # Ctrl-C, SIGTERM, SIGHUP (bioscara.interruption): stop, say where
        interruption.stop_arms([arm], lambda text: Console(stderr=True).print(text, markup=False, highlight=False))
        raise
    finally:
        if gripper is not None:
            gripper.close()
        arm.shutdown()
        arm.bus.close()
    console.print(report.for_terminal(_table(steps), console.is_terminal))
    stats = runner.stats
    console.print(f"communicator: {stats.cycles} cycles at {stats.rate:.1f} Hz (target {runner.frequency:g}), "
                  f"jitter {stats.jitter * 1e6:.0f} us, {stats.overruns} overruns, "
                  f"cycle {stats.duration_mean * 1e3:.2f} ms on the wire")
    console.print(f"virtual time {arm.bus.monotonic():.1f} s, wall time {time.perf_counter() - wall0:.2f} s, "
                  f"{sum(link.transactions for link in arm.bus.stats.links.values())} I2C transactions")
    return steps


def _table(steps: list[Step]) -> Table:
    """Joints as rows, steps as columns; each cell is the target over the final position."""
    table = Table(title="pick and place: target / final position (rad, j2 and gripper in m)")
    table.add_column("")
    for step in steps:
        table.add_column(step.name, justify="right")
    for joint in ("j1", "j2", "j3", "j4"):
        table.add_row(joint, *(f"{s.targets[joint]:+.3f}\n{s.reached[joint]:+.4f}" for s in steps))
    table.add_row("gripper", *(f"{s.gripper_target:.3f}\n{s.gripper:.4f}" for s in steps))
    def worst(joints: tuple[str, ...]) -> float:
        return max(abs(s.reached[j] - s.targets[j]) for s in steps for j in joints)
    table.caption = (f"largest joint error {worst(('j1', 'j3', 'j4')):.5f} rad (j1, j3, j4), "
                     f"{worst(('j2',)) * 1000:.3f} mm (j2)")
    return table
