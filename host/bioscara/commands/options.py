"""Argument types shared by the commands: numbers checked where they are parsed, joint names.

Each raises argparse.ArgumentTypeError with a short message (a 5,000-digit argument is shown
shortened), so argparse reports it as a usage error (exit status 2).
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

JOINTS = ("j1", "j2", "j3", "j4")


def shown(text: str, limit: int = 24) -> str:
    """`text` as an error message may quote it: short, and printable whatever bytes it came from."""
    text = text.encode("utf-8", "backslashreplace").decode("utf-8")
    return repr(text if len(text) <= limit else text[:limit] + "...")


def _number(text: str, kind: type) -> float:
    try:
        return kind(text)
    except (ValueError, OverflowError):
        raise argparse.ArgumentTypeError(f"{shown(text)} is not {'an integer' if kind is int else 'a number'}") from None


def finite(text: str) -> float:
    """A finite number."""
    value = _number(text, float)
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{shown(text)} is not a finite number")
    return value


def positive(unit: str = "") -> Callable[[str], float]:
    """A finite number > 0 (`unit` for the message)."""
    def check(text: str) -> float:
        value = finite(text)
        if value <= 0:
            raise argparse.ArgumentTypeError(f"{shown(text)} must be > 0{' ' + unit if unit else ''}")
        return value
    check.__name__ = "positive number"
    return check


def non_negative(unit: str = "") -> Callable[[str], float]:
    """A finite number >= 0."""
    def check(text: str) -> float:
        value = finite(text)
        if value < 0:
            raise argparse.ArgumentTypeError(f"{shown(text)} must be >= 0{' ' + unit if unit else ''}")
        return value
    check.__name__ = "number >= 0"
    return check


def count(low: int = 1, high: int = 10**9) -> Callable[[str], int]:
    """An integer in low..high."""
    def check(text: str) -> int:
        if len(text.strip()) > 12:
            raise argparse.ArgumentTypeError(f"{shown(text)} is not an integer in {low}..{high}")
        value = int(_number(text, int))
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"{shown(text)} is not an integer in {low}..{high}")
        return value
    check.__name__ = "integer"
    return check


def joint_name(text: str) -> str:
    """A joint as j1 or J1 (printed j1); `all` stays `all`."""
    name = text.strip().lower()
    if name != "all" and name not in JOINTS:
        raise argparse.ArgumentTypeError(f"no joint {shown(text)}; the joints are {', '.join(JOINTS)} (or all)")
    return name


def one_joint(text: str) -> str:
    """A joint as j1 or J1 (printed j1), not `all`."""
    name = text.strip().lower()
    if name not in JOINTS:
        raise argparse.ArgumentTypeError(f"no joint {shown(text)}; the joints are {', '.join(JOINTS)}")
    return name
