"""`bioscara home JOINT|all`: home joints through their home command interfaces, with progress."""

from __future__ import annotations

import argparse
from collections.abc import Callable

from rich.live import Live
from rich.table import Table

from .. import motion
from ..arm import Arm
from ..communicator import Communicator
from ..firmware import protocol as P
from ..session import Session

NAME = "home"
HELP = "home joints toward their configured end stops (Ctrl-C aborts: STOP)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("joints", nargs="+", metavar="JOINT", help="j1..j4 or all")
    parser.add_argument("--direction", type=int, choices=(-1, 1), help="override the configured direction")
    parser.add_argument("--timeout", type=float, default=300.0, help="seconds (default 300)")
    parser.add_argument("--rate", type=float, default=50.0, help="control cycle rate, Hz (default 50)")


class ProgressRunner:
    """Runs the communicator and redraws the progress after every cycle."""

    def __init__(self, comm: Communicator, show: Callable[[], None]) -> None:
        self.comm = comm
        self.show = show

    def run_until(self, predicate: Callable[[], bool], timeout: float) -> None:
        def check() -> bool:
            self.show()
            return predicate()
        self.comm.run_until(check, timeout)


def _progress(arm: Arm) -> Table:
    table = Table()
    for column in ("joint", "state", "flags", "velocity"):
        table.add_column(column)
    for name, aj in arm.joints.items():
        state = "homed" if aj.state.home == 1.0 else ("homing" if aj.joint.is_busy() else "waiting")
        table.add_row(name, state, P.describe_flags(aj.joint.flags), f"{aj.state.velocity:+.4f}")
    return table


def run(args: argparse.Namespace, session: Session) -> int:
    names = list(session.config.joints) if "all" in args.joints else args.joints
    arm = session.arm_of(names)
    comm = Communicator(arm, frequency=args.rate)
    arm.configure()
    arm.activate()
    directions = {name: args.direction for name in names} if args.direction else None
    t0 = arm.bus.monotonic()
    with Live(_progress(arm), console=session.console, transient=session.json,
              auto_refresh=False) as live:
        runner = ProgressRunner(comm, lambda: live.update(_progress(arm), refresh=True))
        motion.home(arm, runner, names, directions, timeout=args.timeout)
    result = {name: {"homed": True, "position": arm[name].state.position} for name in names}
    session.emit({"joints": result, "seconds": arm.bus.monotonic() - t0},
                 f"homed {', '.join(names)} in {arm.bus.monotonic() - t0:.1f} s")
    return 0
