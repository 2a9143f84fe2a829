"""Refresh the simulator's chip cost table from `make bench-chip` output.

    make bench-chip | python bench/chip_costs.py          # or: python bench/chip_costs.py FILE

Reads `name value` lines (chip.scl_held_us.<REGISTER>, chip.loop_hz, chip.service_us_max,
chip.gc_every) and rewrites firmware/joint/sim/chip_costs.json atomically; figures it does not find
keep their current values. Format: /work/wt/_notes/chip_costs.md and the README.
"""

from __future__ import annotations

import json
import os
import pathlib
import subprocess
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parents[1]
TABLE = ROOT / "firmware" / "joint" / "sim" / "chip_costs.json"


def parse(lines: list[str]) -> dict[str, float]:
    figures = {}
    for line in lines:
        parts = line.split()
        if len(parts) == 2 and parts[0].startswith("chip."):
            try:
                figures[parts[0]] = float(parts[1])
            except ValueError:
                pass
    return figures


def refresh(table: dict, figures: dict[str, float], source: str) -> dict:
    held = {name.split(".", 2)[2]: value for name, value in figures.items()
            if name.startswith("chip.scl_held_us.")}
    if held:
        table["scl_held_us"] = held
        table["scl_held_us_default"] = {"read": max(held.values()), "command": max(held.values())}
    if "chip.loop_hz" in figures:
        table["loop_hz"] = figures["chip.loop_hz"]
    if "chip.service_us_max" in figures and "chip.loop_hz" in figures:
        table["gc_pause_us"] = max(0.0, figures["chip.service_us_max"] - 1e6 / figures["chip.loop_hz"])
    if "chip.gc_every" in figures:
        table["gc_every"] = int(figures["chip.gc_every"])
    table["source"] = source
    return table


def main(argv: list[str]) -> int:
    text = pathlib.Path(argv[1]).read_text() if len(argv) > 1 else sys.stdin.read()
    figures = parse(text.splitlines())
    if not figures:
        print("no chip.* figures in the input: nothing refreshed", file=sys.stderr)
        return 1
    rev = subprocess.run(["git", "describe", "--always", "--dirty"], cwd=ROOT, capture_output=True,
                         text=True).stdout.strip() or "unknown revision"
    table = refresh(json.loads(TABLE.read_text()), figures, f"make bench-chip @ {rev}")
    fd, tmp = tempfile.mkstemp(dir=TABLE.parent, suffix=".tmp")
    with os.fdopen(fd, "w") as f:
        json.dump(table, f, indent=2)
        f.write("\n")
    os.replace(tmp, TABLE)
    print(f"{TABLE.relative_to(ROOT)}: {len(figures)} figures from make bench-chip")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
