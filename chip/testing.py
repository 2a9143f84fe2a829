"""pytest helpers for the chip tests: skip when the emulated Pico cannot run; the deployed joint image.

    from chip.testing import joint_image, requires_chip  # noqa: F401 (joint_image is a fixture)
    pytestmark = requires_chip
"""

from __future__ import annotations

from pathlib import Path

import pytest

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
