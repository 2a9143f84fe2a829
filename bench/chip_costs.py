"""Refresh the simulator's chip cost table from `make bench-chip` output.

    make bench-chip | python bench/chip_costs.py          # or: python bench/chip_costs.py FILE

Reads `name value` lines (chip.scl_held_us.<REGISTER> and .v2, chip.loop_hz, chip.loop_seconds,
chip.gc_collections, chip.gc_pause_ms_max) and rewrites firmware/joint/sim/chip_costs.json atomically; figures it does not find
keep their current values. Format: firmware/joint/sim/chip.py and the README ("The simulated arm").
"""

from __future__ import annotations

import json
import os
import pathlib
import subprocess
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "firmware")]

from joint.spec import protocol as P  # noqa: E402

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
    mem = held.pop("v2", None)
    if mem is not None:
        table["scl_held_us_mem"] = mem  # the v2 memory map, served in C
    # By register (a register's figure is the transaction its host makes: a command if writable);
    # the defaults from the implemented ones. The reads of command registers (read.<NAME>) and
    # the rejected frames (reject.<reason>) are not the simulator's.
    held = {name: value for name, value in held.items() if name in P.BY_NAME}
    if held:
        table["scl_held_us"] = held
        implemented = [name for name in held if P.register(name).supported]
        commands = [held[name] for name in implemented if P.register(name).writable]
        reads = [held[name] for name in implemented if not P.register(name).writable]
        table["scl_held_us_default"] = {"read": max(reads or held.values()),
                                        "command": max(commands or held.values())}
    if "chip.loop_hz" in figures:
        table["loop_hz"] = figures["chip.loop_hz"]
    if "chip.gc_collections" in figures:
        iterations = figures.get("chip.loop_hz", 0.0) * figures.get("chip.loop_seconds", 0.0)
        collections = figures["chip.gc_collections"]
        table["gc_every"] = round(iterations / collections) if collections else 0
        table["gc_pause_us"] = figures.get("chip.gc_pause_ms_max", 0.0) * 1000.0
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
