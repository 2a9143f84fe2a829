"""`bioscara move JOINT VALUE`: a position move in joint units, within the joint's limits."""

from __future__ import annotations

import argparse

from .. import motion, report
from ..communicator import Communicator
from ..errors import InvalidArgumentError, NotHomedError
from ..progress import Progress, ProgressRunner
from ..session import Session
from .options import finite, one_joint, positive

NAME = "move"
HELP = "move a homed joint to a position (rad, or m for j2); the joint keeps holding afterwards"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("joint", type=one_joint, help="j1..j4")
    parser.add_argument("value", type=finite, help="target position in joint units (rad, or m for prismatic j2)")
    parser.add_argument("--tolerance", type=positive(), default=1e-3, help="joint units (default 0.001)")
    parser.add_argument("--timeout", type=positive("s"), default=60.0, metavar="S", help="seconds (default 60)")


def run(args: argparse.Namespace, session: Session) -> int:
    arm = session.arm_of([args.joint])
    jc = arm[args.joint].config
    if not jc.min <= args.value <= jc.max:
        raise InvalidArgumentError(report.limits_problem(args.value, jc), joint=args.joint)
    arm.configure()
    if not arm[args.joint].joint.is_homed():
        raise NotHomedError(f"not homed: run `bioscara home {args.joint}` first", joint=args.joint)
    arm.activate()
    comm = Communicator(arm, frequency=50.0)
    start = arm.bus.monotonic()
    state = arm[args.joint].state

    def line() -> str:
        return (f"{args.joint} at {report.value(state.position, jc)}, target {report.value(args.value, jc)}, "
                f"{report.value(state.velocity, jc, per_second=True, digits=3)}, {arm.bus.monotonic() - start:.1f} s")
    with Progress(line, line) as progress:
        final = motion.move_to(arm, ProgressRunner(comm, progress), {args.joint: args.value}, args.tolerance,
                               args.timeout)
    # The firmware stops a position move the host stops watching (deadman); STOP ends the move
    # here, so the joint holds where it is once this command exits.
    arm[args.joint].joint.stop()
    session.emit({**report.joint_ref(args.joint, jc), "target": args.value, "position": final[args.joint]},
                 f"{args.joint} at {report.value(final[args.joint], jc)} (target {report.value(args.value, jc)})")
    return 0
