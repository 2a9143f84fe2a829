"""`bioscara home JOINT|all`: home joints through their home command interfaces, with progress."""

from __future__ import annotations

import argparse
import math

from rich.table import Table

from .. import motion, report
from ..arm import Arm, ArmJoint
from ..communicator import Communicator
from ..progress import Progress, ProgressRunner
from ..session import Session
from .options import joint_name, positive

NAME = "home"
HELP = "home joints toward their configured end stops (Ctrl-C aborts: STOP)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("joints", nargs="+", type=joint_name, metavar="JOINT", help="j1..j4 or all")
    parser.add_argument("--direction", type=int, choices=(-1, 1), help="override the configured direction")
    parser.add_argument("--timeout", type=positive("s"), default=300.0, metavar="S", help="seconds (default 300)")
    parser.add_argument("--rate", type=positive("Hz"), default=50.0, metavar="HZ",
                        help="control cycle rate, Hz (default 50)")


class Travel:
    """How far each joint has moved since homing began, joint units: its measured velocity summed
    over the cycles until it is homed (the position is unknown before, and jumps to the homed frame)."""

    def __init__(self, arm: Arm) -> None:
        self.arm = arm
        self.start = self.last = arm.bus.monotonic()
        self.travel = dict.fromkeys(arm.joints, 0.0)

    def sample(self) -> None:
        now = self.arm.bus.monotonic()
        for name, aj in self.arm.joints.items():
            if aj.state.home != 1.0 and math.isfinite(aj.state.velocity):
                self.travel[name] += aj.state.velocity * (now - self.last)
        self.last = now

    @property
    def elapsed(self) -> float:
        return self.arm.bus.monotonic() - self.start

    def table(self) -> Table:
        table = Table(title=f"homing, {self.elapsed:.1f} s", title_justify="left")
        for column in ("joint", "state", "flags", "travel", "velocity"):
            table.add_column(column, justify="left" if column in ("joint", "state", "flags") else "right")
        for name, aj in self.arm.joints.items():
            table.add_row(name, _state(aj), "|".join(report.flags(aj.joint.flags)) or "-",
                          report.value(self.travel[name], aj.config, digits=3),
                          report.value(aj.state.velocity, aj.config, per_second=True, digits=4))
        return table

    def line(self) -> str:
        return "; ".join(f"{name} {_state(aj)}, travel {report.value(self.travel[name], aj.config, digits=3)}"
                         for name, aj in self.arm.joints.items()) + f"; {self.elapsed:.1f} s"


def _state(aj: ArmJoint) -> str:
    return "homed" if aj.state.home == 1.0 else ("homing" if aj.joint.is_busy() else "waiting")


def run(args: argparse.Namespace, session: Session) -> int:
    names = list(session.config.joints) if "all" in args.joints else list(dict.fromkeys(args.joints))
    arm = session.arm_of(names)
    comm = Communicator(arm, frequency=args.rate)
    arm.configure()
    arm.activate()
    directions = {name: args.direction for name in names} if args.direction else None
    travel = Travel(arm)
    with Progress(travel.table, travel.line, sample=travel.sample) as progress:
        motion.home(arm, ProgressRunner(comm, progress), names, directions, timeout=args.timeout)
    seconds = travel.elapsed
    joints = [{**report.joint_ref(name, arm[name].config), "homed": True, "position": arm[name].state.position,
               "travel": travel.travel[name]} for name in names]
    session.emit({"joints": joints, "seconds": seconds},
                 "\n".join([line for j in joints for line in (
                     f"{j['joint']}: homed at {report.value(j['position'], arm[j['joint']].config)}",
                     f"{j['joint']}: travelled {report.value(j['travel'], arm[j['joint']].config, digits=3)}")]
                     + [f"homed {', '.join(names)} in {seconds:.1f} s"]))
    return 0
