"""Fixtures shared by the host tests: the shipped configuration on the simulated bus."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from bioscara.arm import Arm
from bioscara.bus.sim import SimBus
from bioscara.communicator import Communicator
from bioscara.config import ArmConfig, load_config
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


@pytest.fixture
def config() -> ArmConfig:
    return load_config()


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
