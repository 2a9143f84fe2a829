"""Host side of the motion-safety work: the watchdog our host turns on, limits at the end stop, the
homed-range plausibility check. Through the simulated bus (the real firmware on the simulated arm)."""

from __future__ import annotations

import math

import pytest

from bioscara.arm import Arm
from bioscara.bus.sim import SimBus
from bioscara.errors import InvalidArgumentError, NotHomedError
from bioscara.firmware.spec import protocol as P
from bioscara.joint import LIMIT_SLACK_DEG
from conftest import Recorder


def _home(arm: Arm, name: str) -> None:
    aj = arm[name]
    homing = aj.config.homing
    aj.joint.set_max_acceleration(homing.acceleration)
    aj.joint.home(math.copysign(homing.speed, homing.direction), homing.threshold, homing.current,
                  timeout=60.0)
    aj.joint.set_max_acceleration(aj.config.max_acceleration)


def test_activating_a_joint_turns_its_watchdog_on(arm: Arm, recorder: Recorder) -> None:
    arm.configure()
    arm.activate()
    for aj in arm.joints.values():
        frames = [f for f in recorder.to(aj.config.address) if f and f[0] == P.WATCHDOG]
        payload = P.register(P.WATCHDOG).encode(aj.config.watchdog_ms)
        if arm.protocol == "legacy":
            assert frames == [bytes([P.WATCHDOG]) + payload]
        else:  # the v2 mailbox: the command, its legacy payload padded, CRC, sequence number
            assert frames and all(f[1:1 + len(payload)] == payload for f in frames)


def test_a_position_a_hair_beyond_a_limit_is_on_it(arm: Arm) -> None:
    joint = arm["j4"].joint
    hair = math.radians(0.2 * LIMIT_SLACK_DEG) / abs(joint.transmission.reduction)
    assert joint.within_limits(joint.max + hair) == joint.max
    assert joint.within_limits(joint.min - hair) == joint.min
    with pytest.raises(InvalidArgumentError):
        joint.within_limits(joint.max + 3 * joint.limit_slack)


def test_a_stop_found_far_from_the_end_stop_is_not_taken_as_homed(arm: Arm, bus: SimBus) -> None:
    arm.configure()
    arm.activate()
    joint = arm["j4"].joint
    assert joint.homing_range_check is not None, "default.toml turns the check on"
    _home(arm, "j4")  # from the simulated start near the end stop: plausible
    assert joint.is_homed()
    joint.set_position(0.0)
    for _ in range(150):  # the host keeps polling (its watchdog would stop the move otherwise)
        bus.sleep(0.02)
        joint.get_flags()
    stepper = bus.joint(0x14).stepper
    # An obstacle halfway to the end stop the next homing drives into (motor degrees, link).
    stepper.add_obstacle(stepper.load_angle() + math.degrees(1.5 * abs(joint.transmission.reduction)), 1)
    with pytest.raises(NotHomedError, match="an obstacle"):
        _home(arm, "j4")
    assert not joint.is_homed(), "the implausible stop is not taken"
