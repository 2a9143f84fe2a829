"""Fixtures shared by the host tests: the shipped configuration on the simulated bus."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import pytest

from bioscara.arm import Arm
from bioscara.bus.sim import SimBus
from bioscara.communicator import Communicator
from bioscara.config import ArmConfig, read_config
from bioscara.hardware import open_arm_bus


class Recorder:
    """Wraps a bus's transfer to record every transaction as (address, bytes written, read length)."""

    def __init__(self, bus: SimBus) -> None:
        self.frames: list[tuple[int, bytes | None, int]] = []
        original = bus._transfer_once

        def recording(addr: int, write: bytes | None, read_len: int) -> bytes:
            self.frames.append((addr, write, read_len))
            return original(addr, write, read_len)
        bus._transfer_once = recording  # type: ignore[method-assign]

    def to(self, addr: int) -> list[bytes | None]:
        return [write for a, write, _ in self.frames if a == addr]

    def clear(self) -> None:
        self.frames.clear()


@pytest.fixture(autouse=True)
def private_home(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> Path:
    """Every test gets its own state and config directories, and `sim:` means the in-process
    simulator in virtual time unless a test asks for the shared one (tests/test_sim_service.py),
    which ends by itself after a minute unused."""
    home = tmp_path_factory.mktemp("home")
    monkeypatch.setenv("XDG_STATE_HOME", str(home / "state"))
    monkeypatch.setenv("XDG_CONFIG_HOME", str(home / "config"))
    monkeypatch.setenv("BIOSCARA_BUS", "sim:virtual")
    # A shared simulated arm that a test starts (and a run killed before its teardown leaves
    # behind) ends after a minute unused.
    monkeypatch.setenv("BIOSCARA_SIM_IDLE_EXIT", "1")
    return home


@pytest.fixture
def config() -> ArmConfig:
    """The shipped configuration on the in-process simulator (virtual time)."""
    config = read_config()
    return replace(config, bus=replace(config.bus, url="sim:virtual"))


@pytest.fixture
def bus(config: ArmConfig) -> Iterator[SimBus]:
    bus = open_arm_bus(config)
    assert isinstance(bus, SimBus)
    yield bus
    bus.close()


@pytest.fixture
def recorder(bus: SimBus) -> Recorder:
    return Recorder(bus)


@pytest.fixture(params=["v2", "legacy"])
def arm(request: pytest.FixtureRequest, config: ArmConfig, bus: SimBus) -> Arm:
    """The arm on the simulated bus, once over protocol v2 (what "auto" picks) and once legacy."""
    return Arm(config, bus, request.param)


@pytest.fixture
def comm(arm: Arm) -> Communicator:
    return Communicator(arm, frequency=100.0, realtime_priority=None)
