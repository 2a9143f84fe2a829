"""`bioscara monitor`: a live table of every joint, optionally recorded to CSV or JSON Lines."""

from __future__ import annotations

import argparse
import math

from rich.live import Live
from rich.table import Table

from ..communicator import Communicator, Snapshot
from ..firmware import protocol as P
from ..recording import TraceWriter
from ..session import Session

NAME = "monitor"
HELP = "live position, velocity and flags of every joint (read only: nothing is enabled)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--rate", type=float, default=20.0, help="samples per second (default 20)")
    parser.add_argument("--record", metavar="FILE", help="record to FILE.csv or FILE.jsonl")
    parser.add_argument("--samples", type=int, help="stop after this many samples")
    parser.add_argument("--duration", type=float, help="stop after this many seconds")


def _table(snapshot: Snapshot | None, comm: Communicator) -> Table:
    table = Table(caption=f"{comm.stats.cycles} samples at {comm.stats.rate:.1f} Hz" if snapshot else "")
    for column in ("joint", "position", "velocity", "flags"):
        table.add_column(column, justify="right" if column != "flags" else "left")
    if snapshot is not None:
        for name, s in snapshot.joints.items():
            position = "not homed" if math.isnan(s.position) else f"{s.position:+.5f}"
            table.add_row(name, position, f"{s.velocity:+.5f}", P.describe_flags(s.flags))
    return table


def run(args: argparse.Namespace, session: Session) -> int:
    arm = session.arm
    comm = Communicator(arm, frequency=args.rate)
    arm.configure()
    writer = TraceWriter(args.record, list(arm.joints), args.rate, session.bus.describe()) if args.record else None
    end = None if args.duration is None else session.bus.monotonic() + args.duration
    try:
        with Live(_table(None, comm), console=session.console, auto_refresh=False,
                  transient=session.json) as live:
            def sample() -> bool:
                snapshot = comm.last
                assert snapshot is not None
                if writer is not None:
                    writer.write(snapshot)
                live.update(_table(snapshot, comm), refresh=True)
                return ((args.samples is not None and comm.stats.cycles >= args.samples)
                        or (end is not None and session.bus.monotonic() >= end))
            comm.run_until(sample, timeout=float("inf"), stop_on_fault=False)
    except KeyboardInterrupt:
        pass
    finally:
        if writer is not None:
            writer.close()
    summary = {"samples": comm.stats.cycles, "rate_hz": comm.stats.rate, "errors": comm.stats.errors,
               "record": args.record, "rows": writer.rows if writer else 0}
    errors = f", {comm.stats.errors} with errors (last: {arm.fault})" if comm.stats.errors else ""
    session.emit(summary, f"{comm.stats.cycles} samples" + (f", {writer.rows} rows in {args.record}" if writer else "")
                 + errors)
    return 1 if comm.stats.errors else 0
