"""A protocol v2 reader gets a fresh state at every read while the joint moves, whatever its rate:
the joint repacks the state block at every main-loop pass and judges each frame before the next
read, so no read is dropped as stale and the position changes between any two reads of a move
(issue: j3 seen frozen for 1.4 s at 20 Hz, `bioscara monitor`'s rate)."""

from __future__ import annotations

import pytest

from bioscara.bus.sim import SimBus, SimJointSpec
from bioscara.joint import Joint

J3 = SimJointSpec("J3", 0x13, 35.0, -3.04647, 3.04647, 0.0)
MOVE_STEPS = 200 * 256 * 10  # ten motor turns: several seconds of motion at the default speed


@pytest.mark.parametrize("rate_hz", [20.0, 50.0, 100.0])
def test_a_v2_reader_sees_the_position_change_at_every_read_during_a_move(rate_hz: float) -> None:
    bus = SimBus([J3])
    joint = Joint("j3", 0x13, bus, reduction=35.0, min=-3.0, max=3.0, max_velocity=1.0)
    joint.init()
    joint.use_v2()
    joint.enable(40, 30)
    joint.move_steps(MOVE_STEPS)
    bus.sleep(0.2)  # past the start of the ramp: the joint turns at every read below
    joint.cycle(None)  # the first exchange after the command may still carry its verdict's state
    stale_before = joint.link.stats.stale_states
    positions = []
    for _ in range(int(1.5 * rate_hz)):
        bus.sleep(1.0 / rate_hz)
        assert joint.cycle(None) is not None, f"no fresh state at t = {bus.monotonic():.3f} s"
        positions.append(joint.position_deg)
    assert bus.joint(0x13).stepper.driver_rpm() > 1.0, "the joint still moves: the reads were during the move"
    assert joint.link.stats.stale_states == stale_before
    frozen = [i for i in range(1, len(positions)) if positions[i] == positions[i - 1]]
    assert not frozen, f"position unchanged between reads {frozen[:5]} of {len(positions)}"
