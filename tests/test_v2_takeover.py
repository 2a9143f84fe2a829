"""A joint left in protocol v2 by a host that went away (crashed, unplugged: it never returned the
joint to the legacy map) stops safely and is taken over by a new host of either kind, without a
power cycle. One v2 host per joint at a time (README, "Moving a joint between the maps"): the new
host syncs to the joint's sequence numbers."""

from __future__ import annotations

import pytest

from bioscara.bus.sim import SimBus, SimJointSpec
from bioscara.firmware.spec import protocol as P
from bioscara.firmware.spec import protocol_v2 as V
from bioscara.joint import Joint
from bioscara.link import Command

J1 = SimJointSpec("J1", 0x11, 35.0, -3.04647, 3.04647, 0.0)


def joint(bus: SimBus) -> Joint:
    return Joint("j1", 0x11, bus, reduction=35.0, min=-3.0, max=3.0, max_velocity=1.0)


@pytest.fixture
def abandoned() -> tuple[SimBus, Joint]:
    """A joint speeding up to 10 rpm over v2, its host gone without a word."""
    bus = SimBus([J1])
    old = joint(bus)
    old.init()
    old.use_v2()
    old.enable(40, 30)
    old.write_register("SETRPM", 10.0)
    bus.sleep(0.03)
    assert bus.joint(0x11).stepper.driver_rpm() > 0.5
    return bus, old


def test_the_deadman_stops_a_joint_whose_v2_host_went_silent(abandoned) -> None:
    bus, _ = abandoned
    bus.sleep(0.2)
    assert bus.joint(0x11).stepper.driver_rpm() == 0.0
    assert bus.joint(0x11).switch.protocol == V.PROTOCOL_V2, "still v2 until SILENCE_MS"


def test_a_new_v2_host_takes_over_at_once(abandoned) -> None:
    bus, _ = abandoned
    new = joint(bus)
    new.init()  # the legacy PING finds v2: it syncs in v2 and returns the joint to legacy
    assert new.protocol == "legacy" and bus.joint(0x11).switch.protocol == V.PROTOCOL_LEGACY
    new.check_com()
    new.use_v2()
    new.enable(40, 30)
    samples = []
    for _ in range(3):
        samples.append(new.cycle(Command(P.SETRPM, P.register(P.SETRPM).encode(20.0))))  # 20 motor rpm, unguarded
        bus.sleep(0.01)
    assert None not in samples[1:] and bus.joint(0x11).stepper.driver_rpm() > 0.5
    new.close()
    assert bus.transfer(0x11, bytes([P.PING]), 2)[0] == P.ACK


def test_the_original_host_takes_over_after_the_silence(abandoned) -> None:
    bus, _ = abandoned
    bus.sleep(V.SILENCE_MS / 1000 + 0.05)
    assert bus.transfer(0x11, bytes([P.PING]), 2)[0] == P.ACK, "legacy again, no power cycle"
    legacy = joint(bus)
    legacy.init()
    legacy.enable(40, 30)
    assert legacy.protocol == "legacy" and legacy.is_enabled()
