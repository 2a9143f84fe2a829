"""`bioscara monitor`: every joint live (a table on a terminal, one line per sample otherwise, one
JSON object per sample with --json), optionally recorded to CSV or JSON Lines."""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import sys
from typing import Any

from rich.live import Live
from rich.table import Table

from .. import report
from ..arm import Arm
from ..communicator import Communicator, Snapshot
from ..recording import TraceWriter
from ..session import Session
from .options import count, positive

NAME = "monitor"
HELP = ("live position, velocity and flags of every joint (read only: runs beside the program that "
        "commands the arm, and disturbs nothing)")
USES = ("bus", "protocol", "config", "json")  # it only watches: nothing to take over


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--rate", type=positive("Hz"), default=20.0, metavar="HZ",
                        help="samples per second (default 20)")
    parser.add_argument("--record", metavar="FILE", help="record to FILE.csv or FILE.jsonl")
    parser.add_argument("--samples", type=count(), metavar="N", help="stop after this many samples")
    parser.add_argument("--duration", type=positive("s"), metavar="S", help="stop after this many seconds")


def sample(snapshot: Snapshot, arm: Arm) -> dict[str, Any]:
    """One sample in the common JSON shape."""
    joints = []
    for name, s in snapshot.joints.items():
        jc = arm[name].config
        joints.append({**report.joint_ref(name, jc), "position": None if math.isnan(s.position) else s.position,
                       "velocity": s.velocity, "flags": report.flags(s.flags)})
    return {"time": snapshot.time, "cycle": snapshot.cycle, "joints": joints, "fault": snapshot.fault}


def _table(snapshot: Snapshot | None, comm: Communicator, arm: Arm) -> Table:
    table = Table(caption=f"{comm.stats.cycles} samples at {comm.stats.rate:.1f} Hz" if snapshot else "")
    for column in ("joint", "position", "velocity", "flags"):
        table.add_column(column, justify="right" if column != "flags" else "left")
    if snapshot is not None:
        for name, s in snapshot.joints.items():
            jc = arm[name].config
            position = "not homed" if math.isnan(s.position) else report.value(s.position, jc)
            table.add_row(name, position, report.value(s.velocity, jc, per_second=True),
                          "|".join(report.flags(s.flags)) or "-")
    return table


def _line(snapshot: Snapshot, arm: Arm) -> str:
    parts = [f"{snapshot.time:10.3f} s"]
    for name, s in snapshot.joints.items():
        jc = arm[name].config
        position = "not homed" if math.isnan(s.position) else report.value(s.position, jc)
        parts.append(f"{name} {position} {report.value(s.velocity, jc, per_second=True)} "
                     f"{'|'.join(report.flags(s.flags)) or '-'}")
    return "  ".join(parts)


def run(args: argparse.Namespace, session: Session) -> int:
    arm = session.watched_arm()
    comm = Communicator(arm, frequency=args.rate)
    arm.configure()
    writer = None
    if args.record:
        writer = TraceWriter(args.record, list(arm.joints), args.rate, session.bus.describe(),
                             units={name: report.unit(aj.config) for name, aj in arm.joints.items()})
    end = None if args.duration is None else session.bus.monotonic() + args.duration
    live = session.console.is_terminal and not session.json
    try:
        with (Live(_table(None, comm, arm), console=session.console, auto_refresh=False) if live
              else contextlib.nullcontext()) as display:
            def each() -> bool:
                snapshot = comm.last
                assert snapshot is not None
                if writer is not None:
                    writer.write(snapshot)
                if session.json:
                    sys.stdout.write(json.dumps(sample(snapshot, arm)) + "\n")
                    sys.stdout.flush()
                elif display is not None:
                    display.update(_table(snapshot, comm, arm), refresh=True)
                else:
                    print(_line(snapshot, arm), flush=True)
                return ((args.samples is not None and comm.stats.cycles >= args.samples)
                        or (end is not None and session.bus.monotonic() >= end))
            comm.run_until(each, timeout=float("inf"), stop_on_fault=False)
    except KeyboardInterrupt:
        pass
    finally:
        if writer is not None:
            writer.close()
    summary = {"samples": comm.stats.cycles, "rate_hz": comm.stats.rate, "errors": comm.stats.errors,
               "record": args.record, "rows": writer.rows if writer else 0}
    errors = f", {comm.stats.errors} with errors (last: {arm.fault})" if comm.stats.errors else ""
    session.emit({"summary": summary}, f"{comm.stats.cycles} samples at {comm.stats.rate:.1f} Hz"
                 + (f", {writer.rows} rows in {args.record}" if writer else "") + errors)
    return 1 if comm.stats.errors else 0
