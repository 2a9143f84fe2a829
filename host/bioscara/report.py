"""One shape for what every command prints: joints, addresses, flags, units.

Tables have boxes on a terminal only: piped, they are plain aligned columns.
JSON (`--json`): a joint is named `j1`..`j4`; an I2C address is an integer (17, printed 0x11 for
people); flags are a list of names (`[]` when none); positions are in the joint's `unit` (`rad`
for revolute joints, `m` for prismatic ones), velocities in that unit per second, times in s.
Per-joint outcomes are `{"joint", "address", "ok", "result" | "error"}`. Errors are one line on
stderr (`error: ...`), with exit status 2 for usage and configuration errors, 1 for device errors.
"""

from __future__ import annotations

import math
from typing import Any

from rich.table import Table

from .config import JointConfig
from .firmware.spec import protocol as P


def unit(jc: JointConfig) -> str:
    return "m" if jc.type == "prismatic" else "rad"


def address(addr: int) -> str:
    return f"0x{addr:02x}"


def flags(value: int) -> list[str]:
    return [name for bit, name in P.FLAG_NAMES if value & bit]


def value(x: float | None, jc: JointConfig, *, per_second: bool = False, digits: int = 5) -> str:
    """`x` with the joint's unit: "+1.25000 rad", "-0.00310 m/s"; "-" for None or NaN."""
    if x is None or math.isnan(x):
        return "-"
    return f"{x:+.{digits}f} {unit(jc)}{'/s' if per_second else ''}"


def for_terminal(renderable: Any, terminal: bool) -> Any:
    """A table keeps its box on a terminal; piped (to grep, a file) it is plain aligned columns."""
    if isinstance(renderable, Table) and not terminal:
        renderable.box = None
        renderable.show_edge = False
    return renderable


def joint_ref(name: str, jc: JointConfig) -> dict[str, Any]:
    return {"joint": name, "address": jc.address, "unit": unit(jc)}


def outcome(name: str, jc: JointConfig, result: str | None = None, error: str | None = None) -> dict[str, Any]:
    entry: dict[str, Any] = {"joint": name, "address": jc.address, "ok": error is None}
    entry.update({"result": result} if error is None else {"error": error})
    return entry


def limits_problem(target: float, jc: JointConfig) -> str:
    """Why `target` is refused, with the limits in units, and a hint when it looks like degrees or
    mm: far outside the limits in rad or m (by more than a tenth of the range: just past a limit
    is an overshoot in the right unit) and inside them once converted."""
    u = unit(jc)
    text = f"{target:g} {u} is outside the limits {jc.min:g}..{jc.max:g} {u}"
    beyond = max(jc.min - target, target - jc.max)
    if beyond <= (jc.max - jc.min) / 10:
        return text
    if jc.type == "revolute" and jc.min <= math.radians(target) <= jc.max:
        text += f"; positions are in rad: {target:g} degrees is {math.radians(target):.5f} rad"
    elif jc.type == "prismatic" and jc.min <= target / 1000 <= jc.max:
        text += f"; positions are in m: {target:g} mm is {target / 1000:g} m"
    return text
