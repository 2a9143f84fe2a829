"""Fixtures for the chip tests: skip when the emulated Pico cannot run; the deployed joint image."""

from __future__ import annotations

from pathlib import Path

import pytest

from chip.paths import missing


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    problem = missing()
    if problem is None:
        return
    here = Path(__file__).parent
    for item in items:
        if here in Path(item.fspath).parents:
            item.add_marker(pytest.mark.skip(reason=f"emulated Pico: {problem}"))


@pytest.fixture(scope="session")
def joint_image(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """J1's filesystem as `bioscara flash --joint J1` leaves it on a stock Pico (littlefs image)."""
    from chip import fsimage

    path = tmp_path_factory.mktemp("chip") / "J1-littlefs.img"
    fsimage.joint_image("J1", path)
    return path
