"""`bioscara home JOINT|all`: home joints through their home command interfaces, with progress."""

from __future__ import annotations

import argparse
import contextlib
from collections.abc import Callable

from rich.live import Live
from rich.table import Table

from .. import motion, report
from ..arm import Arm
from ..communicator import Communicator
from ..session import Session
from .options import joint_name, positive

NAME = "home"
HELP = "home joints toward their configured end stops (Ctrl-C aborts: STOP)"
EXAMPLES = (
    ('bioscara home all', 'every joint toward its configured end stop (Ctrl-C sends STOP)'),
    ('bioscara home j3 --direction -1', 'j3 toward its other end stop'),
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("joints", nargs="+", type=joint_name, metavar="JOINT", help="j1..j4 or all")
    parser.add_argument("--direction", type=int, choices=(-1, 1), help="override the configured direction")
    parser.add_argument("--timeout", type=positive("s"), default=300.0, metavar="S", help="seconds (default 300)")
    parser.add_argument("--rate", type=positive("Hz"), default=50.0, metavar="HZ",
                        help="control cycle rate, Hz (default 50)")


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
        table.add_column(column, justify="right" if column == "velocity" else "left")
    for name, aj in arm.joints.items():
        state = "homed" if aj.state.home == 1.0 else ("homing" if aj.joint.is_busy() else "waiting")
        table.add_row(name, state, "|".join(report.flags(aj.joint.flags)) or "-",
                      report.value(aj.state.velocity, aj.config, per_second=True, digits=4))
    return table


def run(args: argparse.Namespace, session: Session) -> int:
    names = list(session.config.joints) if "all" in args.joints else list(dict.fromkeys(args.joints))
    arm = session.arm_of(names)
    comm = Communicator(arm, frequency=args.rate)
    arm.configure()
    arm.activate()
    directions = {name: args.direction for name in names} if args.direction else None
    t0 = arm.bus.monotonic()
    live = session.console.is_terminal and not session.json
    with (Live(_progress(arm), console=session.console, auto_refresh=False, transient=True) if live
          else contextlib.nullcontext()) as display:
        show = (lambda: display.update(_progress(arm), refresh=True)) if display is not None else (lambda: None)
        motion.home(arm, ProgressRunner(comm, show), names, directions, timeout=args.timeout)
    seconds = arm.bus.monotonic() - t0
    joints = [{**report.joint_ref(name, arm[name].config), "homed": True, "position": arm[name].state.position}
              for name in names]
    session.emit({"joints": joints, "seconds": seconds},
                 "\n".join([f"{j['joint']}: homed at {report.value(j['position'], arm[j['joint']].config)}"
                            for j in joints] + [f"homed {', '.join(names)} in {seconds:.1f} s"]))
    return 0
