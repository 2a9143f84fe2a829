"""`bioscara plot FILE`: position and velocity of a monitor recording, as a PNG."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..recording import read_trace
from ..session import Session

NAME = "plot"
HELP = "plot a monitor recording (CSV or JSON Lines) to a PNG"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="a recording made with `bioscara monitor --record`")
    parser.add_argument("-o", "--output", help="PNG path (default: the recording's name with .png)")


def run(args: argparse.Namespace, session: Session) -> int:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    meta, rows = read_trace(args.file)
    output = Path(args.output) if args.output else Path(args.file).with_suffix(".png")
    t0 = rows[0]["time"] if rows else 0.0
    times = [(row["time"] or 0.0) - (t0 or 0.0) for row in rows]
    fig, (pos, vel) = plt.subplots(2, 1, sharex=True, figsize=(10, 6))
    for joint in meta["joints"]:
        pos.plot(times, [row.get(f"{joint}/position") for row in rows], label=joint)
        vel.plot(times, [row.get(f"{joint}/velocity") for row in rows], label=joint)
    pos.set_ylabel("position (rad; j2 m)")
    vel.set_ylabel("velocity (/s)")
    vel.set_xlabel("time (s)")
    pos.legend(loc="upper right")
    fig.suptitle(f"{Path(args.file).name}: {meta['bus']}, spec {meta['spec_hash']}, {meta['rate_hz']} Hz")
    fig.tight_layout()
    fig.savefig(output, dpi=100)
    plt.close(fig)
    session.emit({"png": str(output), "rows": len(rows)}, f"wrote {output} ({len(rows)} samples)")
    return 0
