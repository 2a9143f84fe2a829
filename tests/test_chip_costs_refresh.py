"""`make chip-costs` (bench/chip_costs.py) takes the simulator's per-register stretching from `make
bench-chip`'s lines: a register's figure by its name; the reads of command registers, the rejected
frames, the maxima and the summary lines are not the simulator's and change nothing."""

from __future__ import annotations

import chip_costs

LINES = """\
chip.scl_held_us.PING 50.3
chip.scl_held_us.SETRPM 73
chip.scl_held_us.HOME 77.6
chip.scl_held_us.GETMOTORSTATE 63.6
chip.scl_held_us.read.HOMEOFFSET 50.3
chip.scl_held_us.reject.busy 67.3
chip.scl_held_us_max.PING 52
chip.scl_held_us.v2 14.1
chip.worst.scl_held_us 77.6
chip.over_limit.scl_held_us_max 0
"""


def test_register_figures_reach_the_table_and_nothing_else_does() -> None:
    table = chip_costs.refresh({}, chip_costs.parse(LINES.splitlines()), "test")
    assert table["scl_held_us"] == {"PING": 50.3, "SETRPM": 73.0, "HOME": 77.6, "GETMOTORSTATE": 63.6}
    assert table["scl_held_us_mem"] == 14.1
    # A register declared but not implemented answers with a rejection: not a read's default.
    assert table["scl_held_us_default"] == {"read": 50.3, "command": 77.6}
