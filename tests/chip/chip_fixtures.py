"""Shared by the chip tests: the skip mark naming what is missing, and the deployed joint image.

Not a conftest.py: a second top-level `conftest` module would shadow tests/conftest.py, which
other tests import (`from conftest import Recorder`). Test modules import what they use from here.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from chip.paths import missing

requires_chip = pytest.mark.skipif(missing() is not None, reason=f"emulated Pico: {missing()}")


@pytest.fixture(scope="session")
def joint_image(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """J1's filesystem as `bioscara flash --joint J1` leaves it on a stock Pico (littlefs image)."""
    from chip import fsimage

    path = tmp_path_factory.mktemp("chip") / "J1-littlefs.img"
    fsimage.joint_image("J1", path)
    return path
