"""Joint API semantics on the simulated bus: guards, the original's bugs fixed, waits with timeouts."""

from __future__ import annotations

import math

import pytest

from bioscara.bus.sim import SimBus
from bioscara.config import ArmConfig
from bioscara.errors import (
    BioscaraError, IncorrectStateError, InvalidArgumentError, NotEnabledError, NotHomedError, NotInitError,
)
from bioscara.firmware.motion.hal import MAGNET_MISSING, MAGNET_OK, MAGNET_WEAK
from bioscara.firmware.spec import protocol as P
from bioscara.joint import BlockingCommand, Joint, WaitTimeoutError

from conftest import Recorder


def make(config: ArmConfig, bus: SimBus, name: str = "j1") -> Joint:
    jc = config.joints[name]
    joint = Joint(name, jc.address, bus, reduction=jc.reduction, min=jc.min, max=jc.max,
                  max_velocity=jc.max_velocity)
    joint.init()
    return joint


def homed(config: ArmConfig, bus: SimBus, name: str = "j1") -> Joint:
    joint = make(config, bus, name)
    jc = config.joints[name]
    joint.enable(jc.drive_current, jc.hold_current)
    joint.set_max_acceleration(jc.homing.acceleration)
    joint.home(math.copysign(jc.homing.speed, jc.homing.direction), jc.homing.threshold, jc.homing.current,
               timeout=60)
    joint.enable(jc.drive_current, jc.hold_current)
    joint.set_max_acceleration(jc.max_acceleration)
    joint.set_max_velocity(jc.max_velocity)
    return joint


def test_commands_before_init_raise_not_init(config: ArmConfig, bus: SimBus) -> None:
    joint = Joint("j1", 0x11, bus)
    with pytest.raises(NotInitError):
        joint.stop()
    joint.init()
    joint.init()  # harmless a second time
    joint.close()
    joint.close()
    with pytest.raises(NotInitError):
        joint.get_velocity()


def test_a_ping_answered_outside_the_legacy_map_leaves_the_flags(config: ArmConfig, bus: SimBus) -> None:
    """A joint between maps (an S32 leaving v2 answers 00 00 to a PING for a moment) is not
    reporting flags: the host keeps the ones it had, and no false 'rebooted' follows."""
    joint = make(config, bus)
    assert not joint.is_enabled()
    original = bus._transfer_once
    zeros = [bytes(2)]

    def between_maps(addr: int, write: bytes | None, read_len: int) -> bytes:
        if write == bytes([P.PING]) and zeros:
            return zeros.pop()
        return original(addr, write, read_len)
    bus._transfer_once = between_maps  # type: ignore[method-assign]
    with pytest.raises(BioscaraError):
        joint.check_com()
    assert not joint.is_enabled()
    joint.check_com()
    assert joint.disabled_cause is None


def test_motion_needs_enabled_and_homed(config: ArmConfig, bus: SimBus) -> None:
    joint = make(config, bus)
    with pytest.raises(NotEnabledError):
        joint.set_velocity(0.1)
    joint.enable(20, 20)
    with pytest.raises(NotHomedError):
        joint.set_position(0.0)
    with pytest.raises(NotHomedError):
        joint.get_position()
    joint.move_steps(10)  # allowed before homing, as the original


def test_out_of_range_values_are_rejected_and_never_sent(config: ArmConfig, bus: SimBus, recorder: Recorder) -> None:
    joint = homed(config, bus)
    recorder.clear()
    for call in (lambda: joint.set_position(3.5), lambda: joint.set_position(math.nan),
                 lambda: joint.set_velocity(1.5), lambda: joint.set_velocity(math.inf),
                 lambda: joint.enable(120, 20), lambda: joint.set_max_velocity(-1.0),
                 lambda: joint.enable_stallguard(300), lambda: joint.set_brake_mode(5)):
        with pytest.raises(InvalidArgumentError):
            call()
    assert recorder.frames == []


def test_a_rejected_homing_call_changes_nothing(config: ArmConfig, bus: SimBus, recorder: Recorder) -> None:
    joint = make(config, bus)
    joint.enable(20, 20)
    recorder.clear()
    for velocity in (0.0, 0.001, 10.0, math.nan):  # 0.001 rad/s is 0.33 motor RPM: below 1
        with pytest.raises(InvalidArgumentError):
            joint.start_homing(velocity, 30, 15)
    assert recorder.frames == [] and joint.offset == 0.0 and joint.current_blocking is BlockingCommand.NONE


def test_homing_twice_is_an_incorrect_state(config: ArmConfig, bus: SimBus) -> None:
    joint = make(config, bus)
    joint.enable(20, 20)
    joint.start_homing(-0.03, 30, 15)
    with pytest.raises(IncorrectStateError):
        joint.start_homing(-0.03, 30, 15)


def test_a_homing_that_takes_too_long_times_out_and_stops(config: ArmConfig, bus: SimBus) -> None:
    joint = make(config, bus)
    joint.enable(20, 20)
    joint.set_max_acceleration(0.01)
    with pytest.raises(WaitTimeoutError, match="still busy after 0.5 s"):
        joint.home(0.03, 30, 15, timeout=0.5)  # toward the far end stop, 6 rad away
    assert joint.current_blocking is BlockingCommand.NONE
    assert not joint.is_busy() and not joint.is_homed(), "STOP aborted it in the firmware"


def test_homing_offset_is_restored_by_a_new_host(config: ArmConfig, bus: SimBus) -> None:
    joint = homed(config, bus)
    position = joint.get_position()
    joint.close()
    again = make(config, bus)
    assert again.offset == pytest.approx(config.joints["j1"].min, rel=1e-7), "float32 on the wire"
    assert again.get_position() == pytest.approx(position, abs=1e-3)


def test_flags_of_the_current_cycle_cost_no_extra_transaction(config: ArmConfig, bus: SimBus,
                                                              recorder: Recorder) -> None:
    joint = homed(config, bus)
    joint.get_velocity()
    recorder.clear()
    joint.set_velocity(0.1)
    assert [w[0] for w in recorder.to(0x11)] == [P.SETRPM], "fresh flags: no PING"
    bus.sleep(0.05)
    recorder.clear()
    joint.set_velocity(0.0)
    assert [w[0] for w in recorder.to(0x11)] == [P.PING, P.SETRPM], "stale flags: refreshed first"


def test_identity_and_rejection_details(config: ArmConfig, bus: SimBus) -> None:
    joint = make(config, bus, "j3")
    identity = joint.identity()
    assert identity.joint_id == 3 and identity.spec_matches and identity.protocol == P.PROTOCOL_VERSION
    joint.enable(10, 10)
    joint.start_homing(0.05, 25, 10)
    with pytest.raises(IncorrectStateError, match="rejected CHECKORIENTATION: a blocking command is already"):
        joint.write_register("CHECKORIENTATION", 2.0)
    assert joint.last_reject().reason == P.REJECT_BUSY


@pytest.mark.parametrize("reports, why", [(MAGNET_WEAK, "magnet too weak"), (MAGNET_MISSING, "no magnet"),
                                          (MAGNET_OK, "too noisy at rest \\(weak or missing magnet\\)")])
def test_a_homing_the_joint_refuses_says_why(config: ArmConfig, bus: SimBus, reports: int, why: str) -> None:
    """A weak magnet (the simulator's fault mode): the joint refuses to home and the host's error
    quotes its reason (HOMINGRESULT), not only "not homed": the encoder's status when it reports the
    magnet, the noise check when its status says nothing (a marginal magnet)."""
    joint = make(config, bus)
    bus.joint(0x11).stepper.weaken_magnet(reports=reports)
    jc = config.joints["j1"]
    joint.enable(jc.drive_current, jc.hold_current)
    before = bus.joint(0x11).stepper.rotor_angle()
    with pytest.raises(NotHomedError, match=why):
        joint.home(math.copysign(jc.homing.speed, jc.homing.direction), jc.homing.threshold, jc.homing.current,
                   timeout=60)
    assert not joint.is_homed()
    assert abs(bus.joint(0x11).stepper.rotor_angle() - before) < 5.0  # refused before it drove
