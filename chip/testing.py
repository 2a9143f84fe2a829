"""pytest helpers for the chip tests, loaded as a plugin (`-p chip.testing` in pyproject.toml), so
its fixtures are there in every test module: skip when the emulated Pico cannot run; the deployed
joint image.

    from chip.testing import requires_chip
    pytestmark = requires_chip

    def test_x(joint_image): ...   # J1's littlefs image, as `bioscara flash --joint J1` leaves it
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest
import serial

from .paths import missing

_problem = missing()
requires_chip = pytest.mark.skipif(_problem is not None, reason=f"emulated Pico: {_problem}")


@pytest.fixture(scope="session")
def joint_image(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """J1's filesystem as `bioscara flash --joint J1` leaves it on a stock Pico (a littlefs image)."""
    from . import fsimage

    path = tmp_path_factory.mktemp("chip") / "J1-littlefs.img"
    fsimage.joint_image("J1", path)
    return path

_cp_problem = missing("circuitpython")
requires_circuitpython = pytest.mark.skipif(_cp_problem is not None,
                                            reason=f"emulated CircuitPython Pico: {_cp_problem}")


def read_console_until(port: str, marker: bytes, timeout: float) -> bytes:
    """What the board's serial console prints until `marker` (or `timeout` s: the caller asserts)."""
    with serial.Serial(port, timeout=0.2) as console:
        got = b""
        end = time.monotonic() + timeout
        while marker not in got and time.monotonic() < end:
            got += console.read(4096)
    return got
