"""`bioscara plot FILE`: position and velocity of a monitor recording, as a PNG, one axis per unit."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..recording import read_trace
from ..session import Session

NAME = "plot"
HELP = "plot a monitor recording (CSV or JSON Lines) to a PNG: position and velocity, one axis per unit"
EXAMPLES = (
    ('bioscara plot run.csv', 'run.png: position and velocity of the recording'),
    ('bioscara plot run.csv -o homing.png', 'to another file'),
)
USES = ("json",)
_DEFAULT_UNITS = {"j2": "m"}  # recordings from before units were recorded: the shipped arm's


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="a recording made with `bioscara monitor --record`")
    parser.add_argument("-o", "--output", help="PNG path (default: the recording's name with .png)")


def run(args: argparse.Namespace, session: Session) -> int:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    meta, rows = read_trace(args.file)
    output = Path(args.output) if args.output else Path(args.file).with_suffix(".png")
    units = {joint: str(meta.get("units", {}).get(joint) or _DEFAULT_UNITS.get(joint, "rad"))
             for joint in meta["joints"]}
    groups = sorted(set(units.values()), key=lambda u: (u != "rad", u))  # rad first, then m
    t0 = rows[0]["time"] if rows else 0.0
    times = [(row["time"] or 0.0) - (t0 or 0.0) for row in rows]
    fig, axes = plt.subplots(2 * len(groups), 1, sharex=True, figsize=(10, 3 * len(groups) + 2), squeeze=False)
    for i, unit in enumerate(groups):
        pos, vel = axes[2 * i][0], axes[2 * i + 1][0]
        for joint in (j for j in meta["joints"] if units[j] == unit):
            pos.plot(times, [row.get(f"{joint}/position") for row in rows], label=joint)
            vel.plot(times, [row.get(f"{joint}/velocity") for row in rows], label=joint)
        pos.set_ylabel(f"position ({unit})")
        vel.set_ylabel(f"velocity ({unit}/s)")
        pos.legend(loc="upper right")
        vel.legend(loc="upper right")
    axes[-1][0].set_xlabel("time (s)")
    fig.suptitle(f"{Path(args.file).name}: {meta['bus']}, spec {meta['spec_hash']}, {meta['rate_hz']} Hz")
    fig.tight_layout()
    try:
        fig.savefig(output, dpi=100)
    except OSError as exc:
        from ..errors import InvalidArgumentError
        raise InvalidArgumentError(f"cannot write {output}: {exc.strerror or exc}") from None
    finally:
        plt.close(fig)
    session.emit({"png": str(output), "rows": len(rows), "axes": [f"position ({u})" for u in groups]
                  + [f"velocity ({u}/s)" for u in groups]}, f"wrote {output} ({len(rows)} samples)")
    return 0
