"""The simulator charges what the chip costs: the original host's one-joint cycle (ANGLEMOVED,
GETENCODERRPM, SETRPM back to back) at 400 kHz takes as long on the simulated bus, with the
repository's cost table (firmware/joint/sim/chip_costs.json), as on the emulated Pico running the
deployed firmware: within 20 %. A table left stale by a firmware change fails here; `make
chip-costs` refreshes it from `make bench-chip`.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from bioscara.bus.sim import SimBus
from bioscara.config import read_config
from bioscara.hardware import sim_joint_specs
from chip.board import EmulatedPico
from chip.i2c import JointBusClient, joint_bus_plugin
from chip.joint_devices import JOINT_DEVICES_PLUGIN
from chip.testing import joint_image, requires_chip  # noqa: F401 (a fixture)
from chip_bus import ADDRESS, CYCLE_NAMES, cycle_figure, enable, legacy_transaction, wait_on_bus
from joint.sim.chip import ChipCosts

pytestmark = requires_chip

CYCLES = 10


@pytest.fixture(scope="module")
def chip_cycle_us(joint_image: Path) -> Iterator[float]:  # noqa: F811 (the fixture)
    with EmulatedPico(joint_image, plugins=[JOINT_DEVICES_PLUGIN, joint_bus_plugin(khz=400)]) as pico:
        bus = JointBusClient(pico)
        wait_on_bus(bus)
        assert enable(bus), "the emulated joint did not enable"
        span, failed = cycle_figure(bus, [legacy_transaction(n) for n in CYCLE_NAMES], cycles=CYCLES)
        assert failed == 0 and span is not None
        yield span


def simulated_cycle_us() -> float:
    """The same cycle on the simulated J1 (enabled as on the chip), in the bus's virtual time."""
    specs = [spec for spec in sim_joint_specs(read_config()) if spec.address == ADDRESS]
    bus = SimBus(specs, speed_hz=400_000)
    write, read_len = legacy_transaction("SETUP")
    bus.transfer(ADDRESS, write, read_len)
    bus.sleep(0.01)
    spans = []
    for _ in range(CYCLES):
        start = bus.monotonic()
        for name in CYCLE_NAMES:
            bus.transfer(ADDRESS, *legacy_transaction(name))
        spans.append((bus.monotonic() - start) * 1e6)
        bus.sleep(0.01)
    bus.close()
    return sorted(spans)[len(spans) // 2]


def test_the_simulated_cycle_costs_what_the_chip_cycle_costs(chip_cycle_us: float) -> None:
    simulated = simulated_cycle_us()
    costs = ChipCosts.load()
    assert abs(simulated / chip_cycle_us - 1.0) <= 0.2, (
        f"one-joint cycle at 400 kHz: simulator {simulated:.0f} us, emulated chip {chip_cycle_us:.0f} us; "
        f"the cost table ({costs.source}) is stale: run `make chip-costs`")
