"""End to end through the simulated bus, which runs the real firmware on simulated steppers."""

from __future__ import annotations

import json
import logging
import math
import re
from dataclasses import replace
from pathlib import Path

import pytest

from bioscara import motion
from bioscara.arm import Arm, Lifecycle, Mode
from bioscara.bus.sim import SimBus
from bioscara.communicator import Communicator
from bioscara.config import ArmConfig
from bioscara.errors import CommError, NotEnabledError, NotHomedError, StalledError
from bioscara.firmware.config import schema as firmware_config
from bioscara.firmware.core.supervise import DETECTOR_NAMES
from bioscara.firmware.spec import protocol as P
from bioscara.firmware.sim import mechanics
from bioscara.gripper import MockGripper
from bioscara.hardware import open_arm_bus, sim_joint_specs

from conftest import Recorder


def _home_all(arm: Arm, comm: Communicator) -> None:
    arm.configure()
    arm.activate()
    motion.home(arm, comm, timeout=120)


def test_homing_drives_each_joint_to_its_end_stop_and_measures_where_it_is(arm: Arm, comm: Communicator,
                                                                           bus: SimBus) -> None:
    _home_all(arm, comm)
    for aj in arm.joints.values():
        end = aj.config.max if aj.config.homing.direction > 0 else aj.config.min
        assert aj.state.home == 1.0
        assert aj.joint.offset == end, "the offset is the end stop homing drove into"
    comm.run_for(0.5)
    for name, aj in arm.joints.items():
        true = bus.joint_position(aj.config.address)
        error_deg = math.degrees(abs(aj.state.position - true) * abs(aj.config.reduction))
        # The simulated arm's transmission and stops deflect under the homing push.
        bound = mechanics.homing_error_bound_deg(name.upper(), aj.config.homing.current)
        assert error_deg < bound, f"{name}: measured position off by {error_deg:.2f} motor degrees"


def test_a_position_move_brings_every_joint_to_its_target(arm: Arm, comm: Communicator, bus: SimBus) -> None:
    _home_all(arm, comm)
    targets = {"j1": 0.5, "j2": 0.2, "j3": -1.0, "j4": 1.5}
    final = motion.move_to(arm, comm, targets, tolerance=1e-3, timeout=60)
    for name, target in targets.items():
        assert abs(final[name] - target) <= 1e-3
        true = bus.joint_position(arm[name].config.address)
        bound = mechanics.position_error_bound_deg(name.upper(), arm[name].config.homing.current)
        assert math.degrees(abs(true - target) * abs(arm[name].config.reduction)) < bound, (name, true)


def test_velocity_mode_turns_at_the_commanded_speed_and_zero_stops_it(arm: Arm, comm: Communicator) -> None:
    _home_all(arm, comm)
    arm.switch_modes(start=["j1/velocity"], stop=["j1/position"])
    arm.set_command("j1", "velocity", 0.2)
    start = arm["j1"].state.position
    comm.run_for(2.0)
    assert abs(arm["j1"].state.velocity - 0.2) < 0.01
    assert arm["j1"].state.position - start > 0.3
    arm.set_command("j1", "velocity", 0.0)
    comm.run_for(1.0)
    assert abs(arm["j1"].state.velocity) < 1e-3


def test_the_gripper_reaches_both_widths(comm: Communicator, bus: SimBus, config: ArmConfig, tmp_path) -> None:
    assert config.gripper is not None
    gripper = MockGripper(replace(config.gripper, state_file=str(tmp_path / "gripper")), clock=bus.monotonic)
    gripper.init()
    gripper.enable()
    for width in (config.gripper.max, config.gripper.min):
        gripper.set_position(width)
        comm.run_until(lambda: gripper.get_velocity() == 0.0, timeout=5)
        assert gripper.get_position() == pytest.approx(width)
    gripper.disable()


def test_deactivate_disables_every_joint_and_shutdown_finalizes(arm: Arm, comm: Communicator) -> None:
    arm.configure()
    arm.activate()
    comm.run_for(0.2)
    arm.deactivate()
    assert all(not aj.joint.is_enabled() for aj in arm.joints.values())
    arm.shutdown()
    assert arm.lifecycle is Lifecycle.FINALIZED
    assert arm.fault is None


def test_a_stall_during_a_move_disables_the_joints(arm: Arm, comm: Communicator, bus: SimBus) -> None:
    _home_all(arm, comm)
    arm.switch_modes(start=["j1/velocity"])
    arm.set_command("j1", "velocity", 0.36)  # 120 motor rpm: where the original stall detection works
    comm.run_for(1.0)
    stepper = bus.joint(0x11).stepper
    stepper.add_obstacle(stepper.load_angle() + 60.0, 1)
    with pytest.raises(StalledError) as stall:
        comm.run_until(lambda: False, timeout=3)
    assert stall.value.joint == "j1" and arm.fault is stall.value
    assert arm.lifecycle is Lifecycle.INACTIVE, "the arm deactivated itself"
    comm.run_for(0.1)
    assert all(not aj.joint.is_enabled() for aj in arm.joints.values()), "every joint is disabled"


def test_the_deadman_stops_a_joint_when_the_host_stops_writing(arm: Arm, comm: Communicator, bus: SimBus) -> None:
    _home_all(arm, comm)
    arm.switch_modes(start=["j4/velocity"])
    arm.set_command("j4", "velocity", -1.0)  # away from the end stop it homed on
    comm.run_for(1.0)
    joint = bus.joint(0x14)
    assert abs(joint.stepper.encoder_rpm()) > 50
    bus.sleep(arm["j4"].config.watchdog_ms / 1000 + 0.05)  # the host goes silent past its watchdog
    assert joint.core.flags & P.FLAG_NOTENABLED
    assert joint.stepper.driver_rpm() == 0.0, "the firmware stopped the motor on its own"
    bus.sleep(0.5)
    assert abs(joint.stepper.encoder_rpm()) < 1


def test_the_simulated_joints_run_the_shipped_joint_configurations(config: ArmConfig) -> None:
    """Every constant of firmware/joint/config/J1..J4.json (stall detector, quick stop, safe action,
    homing limits), at the address the host's configuration gives the joint."""
    config = replace(config, joints={**config.joints, "j1": replace(config.joints["j1"], address=0x21)})
    bus = open_arm_bus(config)
    assert isinstance(bus, SimBus)
    for name, jc in config.joints.items():
        shipped = json.loads((Path(firmware_config.__file__).parent / f"{name.upper()}.json").read_text())
        joint = bus.joint(jc.address)
        cfg = joint.cfg
        assert cfg.joint == name.upper() and cfg.address == jc.address
        for key in ("deadman_ms", "stop_deceleration", "safe_action"):
            assert getattr(cfg, key) == shipped[key], (name, key)
        for section in ("boot", "stall", "homing"):
            for key, value in shipped[section].items():
                assert getattr(getattr(cfg, section), key) == value, (name, section, key)
        assert joint.core.detector == DETECTOR_NAMES.index(shipped["stall"]["detector"])
    bus.close()


def _seeded_arm(config: ArmConfig, seed: int, noise: str) -> tuple[Arm, Communicator, SimBus]:
    config = replace(config, sim=replace(config.sim, seed=seed, noise=noise))
    bus = open_arm_bus(config)
    assert isinstance(bus, SimBus)
    arm = Arm(config, bus, "v2")
    return arm, Communicator(arm, frequency=100.0, realtime_priority=None), bus


# Several simulated arms: seeds (the encoders' error phases, the ISR's) and the harsh corner, whose
# encoder noise keeps every joint's closed loop correcting after a move (issue 25).
@pytest.mark.parametrize("seed,noise", [(1, "nominal"), (2, "nominal"), (3, "nominal"), (1, "harsh")])
def test_a_quiet_host_after_a_move_leaves_every_joint_holding_its_target(config: ArmConfig, seed: int, noise: str,
                                                                         caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger="bioscara.sim")  # the joints' consoles
    arm, comm, bus = _seeded_arm(config, seed, noise)
    _home_all(arm, comm)
    targets = {"j1": 0.5, "j2": 0.2, "j3": -1.0, "j4": 1.5}
    motion.move_to(arm, comm, targets, tolerance=1e-3, timeout=60)
    bus.sleep(5.0)  # the program does something else: nobody talks to the joints
    comm.run_for(0.1)
    for name, target in targets.items():
        assert arm[name].joint.is_enabled(), f"{name} was disabled while it held its target"
        assert arm[name].state.position == pytest.approx(target, abs=2e-3)
    assert not [line for line in caplog.messages if "deadman" in line]


def test_a_move_the_host_falls_silent_during_is_stopped_short_of_its_target(config: ArmConfig) -> None:
    arm, comm, bus = _seeded_arm(config, 1, "nominal")
    _home_all(arm, comm)
    targets = {}
    for name, aj in arm.joints.items():  # across the range, away from the stop it homed on
        low, high = aj.config.min, aj.config.max
        targets[name] = low + 0.1 * (high - low) if aj.config.homing.direction > 0 else high - 0.1 * (high - low)
        arm.switch_modes(start=[f"{name}/position"])
        arm.set_command(name, "position", targets[name])
    comm.run_for(0.25)
    silent_at = {name: bus.joint_position(aj.config.address) for name, aj in arm.joints.items()}
    speed = {name: abs(bus.joint(aj.config.address).stepper.driver_rpm()) * 2 * math.pi / 60 / abs(aj.config.reduction)
             for name, aj in arm.joints.items()}  # units/s: the driver's, the encoder's estimate lags
    watchdog_s = config.joints["j1"].watchdog_ms / 1000
    bus.sleep(watchdog_s + 0.6)  # the host falls silent mid-way
    for name, aj in arm.joints.items():
        joint = bus.joint(aj.config.address)
        assert joint.core.flags & P.FLAG_NOTENABLED, f"{name} went on without its host"
        stopped = bus.joint_position(aj.config.address)
        bus.sleep(0.2)
        assert bus.joint_position(aj.config.address) == pytest.approx(stopped, abs=1e-4), f"{name} still moves"
        # It may speed up until the watchdog fires (and a main-loop tick), then the quick stop brakes.
        fastest = min(aj.config.max_velocity, speed[name] + aj.config.max_acceleration * (watchdog_s + 0.01))
        quick_stop = joint.cfg.stop_deceleration * 2 * math.pi / 200 / abs(aj.config.reduction)  # units/s^2
        reach = fastest * (watchdog_s + 0.01) + fastest * fastest / (2 * quick_stop)
        assert abs(stopped - silent_at[name]) < 1.1 * reach, f"{name} went on from {silent_at[name]} to {stopped}"
        assert abs(targets[name] - silent_at[name]) > 1.1 * reach, "the move would have ended anyway"


@pytest.mark.parametrize("arm", ["legacy"], indirect=True)
def test_releasing_velocity_mode_while_turning_commands_zero(arm: Arm, comm: Communicator, bus: SimBus) -> None:
    _home_all(arm, comm)
    recorder = Recorder(bus)
    arm.switch_modes(start=["j3/velocity"])
    arm.set_command("j3", "velocity", -0.5)
    comm.run_for(1.0)
    recorder.clear()
    arm.switch_modes(stop=["j3/velocity"])
    assert recorder.to(0x13) == [bytes([P.STOP, 0])], "0 RPM, without guards that could refuse it"
    comm.run_for(1.0)
    assert abs(arm["j3"].state.velocity) < 1e-3, "the joint stopped although reads continue"


def test_a_joint_reboot_is_detected_and_motion_refused_until_rehomed(arm: Arm, comm: Communicator,
                                                                     bus: SimBus) -> None:
    _home_all(arm, comm)
    arm.switch_modes(start=["j2/position"])
    comm.run_for(0.2)
    bus.joint(0x12).power_cycle()
    with pytest.raises(CommError):  # it ignores its address while it boots
        comm.run_until(lambda: False, timeout=2)
    assert arm.lifecycle is Lifecycle.INACTIVE
    arm.recover()
    bus.sleep(2.0)
    arm.configure()
    arm.activate()
    assert arm["j2"].state.home == 0.0 and math.isnan(arm["j2"].state.position)
    assert arm["j1"].state.home == 1.0, "the other joints stayed homed"
    with pytest.raises(NotHomedError):
        arm.switch_modes(start=["j2/position"])
    with pytest.raises(NotHomedError):
        arm["j2"].joint.set_position(0.1)
    motion.home(arm, comm, joints=["j2"], timeout=60)
    motion.move_to(arm, comm, {"j2": 0.3}, tolerance=1e-3, timeout=30)


def test_a_missing_joint_is_a_comm_error_after_retries_and_nothing_changes(config: ArmConfig) -> None:
    specs = [spec for spec in sim_joint_specs(config) if spec.address != 0x14]
    bus = SimBus(specs)
    arm = Arm(config, bus)
    with pytest.raises(CommError, match="0x14"):
        arm.configure()
    assert arm.lifecycle is Lifecycle.UNCONFIGURED
    assert bus.stats.link(0x14).failed_attempts == config.bus.attempts
    assert not any(aj.joint.is_open for aj in arm.joints.values()), "the joints opened before were closed"
    assert arm["j4"].joint.flags == P.FLAGS_AT_BOOT, "flags only come from successful transfers"


def test_mock_hardware_means_the_simulated_bus(config: ArmConfig) -> None:
    mock = replace(config, bus=replace(config.bus, url="smbus:1", use_mock_hardware=True))
    bus = open_arm_bus(mock)
    assert isinstance(bus, SimBus)
    bus.close()


def test_a_fault_during_homing_is_raised_at_once_with_its_cause(arm: Arm, comm: Communicator,
                                                                  bus: SimBus) -> None:
    arm.configure()
    arm.activate()
    bus.joint(0x12).connected = False
    t0 = bus.monotonic()
    with pytest.raises(CommError, match="0x12"):
        motion.home(arm, comm, timeout=300)
    assert bus.monotonic() - t0 < 1.0, "not after the 300 s timeout"
    assert arm.lifecycle is Lifecycle.INACTIVE


def test_a_failed_activation_leaves_no_joint_energized(arm: Arm, bus: SimBus) -> None:
    arm.configure()
    original = bus._transfer_once

    def refuse_j3_stall_guard(addr: int, write: bytes | None, read_len: int) -> bytes:
        if addr == 0x13 and write and write[0] == P.ENABLESTALLGUARD:
            raise OSError(121, "NACK")
        return original(addr, write, read_len)
    bus._transfer_once = refuse_j3_stall_guard  # type: ignore[method-assign]
    with pytest.raises(CommError):
        arm.activate()
    assert arm.lifecycle is Lifecycle.INACTIVE
    for address in (0x11, 0x12, 0x13):
        assert bus.joint(address).core.flags & P.FLAG_NOTENABLED, hex(address)


def test_releasing_velocity_mode_works_on_a_joint_already_disabled(arm: Arm, comm: Communicator,
                                                                   bus: SimBus) -> None:
    _home_all(arm, comm)
    arm.switch_modes(start=["j1/velocity"])
    arm.set_command("j1", "velocity", 0.1)
    comm.run_for(0.5)
    arm["j1"].joint.set_drive_current(0)  # the joint is disabled behind the arm's back
    arm.switch_modes(start=["j1/position"], stop=["j1/velocity"])
    assert arm["j1"].modes == {Mode.POSITION}


def test_a_homing_cut_short_by_a_fault_does_not_return_after_recovery(arm: Arm, comm: Communicator,
                                                                      bus: SimBus) -> None:
    arm.configure()
    arm.activate()
    arm.switch_modes(start=["j4/home"])
    arm.set_command("j4", "home", -1)  # toward the far end stop: still homing when the fault comes
    comm.run_for(0.2)
    bus.joint(0x11).connected = False
    with pytest.raises(CommError):
        comm.run_until(lambda: False, timeout=1)
    bus.joint(0x11).connected = True
    arm.recover()
    arm.configure()
    arm.activate()
    comm.run_for(0.2)
    assert arm.lifecycle is Lifecycle.ACTIVE
    assert not bus.joint(0x14).core.flags & P.FLAG_NOTENABLED, "j4 stays enabled"


def test_flags_survive_a_failed_transfer(arm: Arm, bus: SimBus) -> None:
    arm.configure()
    joint = arm["j1"].joint
    joint.enable(20, 20)
    assert joint.flags == P.FLAG_NOTHOMED
    bus.joint(0x11).connected = False
    with pytest.raises(CommError):
        joint.stop()
    assert joint.flags == P.FLAG_NOTHOMED, "flags only come from successful transfers"


def test_a_reboot_between_cycles_is_seen_as_not_homed(arm: Arm, comm: Communicator, bus: SimBus) -> None:
    _home_all(arm, comm)
    arm.switch_modes(start=["j2/position"])
    comm.run_for(0.2)
    bus.joint(0x12).power_cycle()
    bus.sleep(1.0)  # a brown-out: back on the bus before the host's next cycle
    with pytest.raises(NotEnabledError):  # the original's guard order: enabled, then homed
        comm.run_until(lambda: False, timeout=1)
    assert arm["j2"].state.home == 0.0, "the cycle's read saw NOTHOMED"
    assert arm.lifecycle is Lifecycle.INACTIVE


def test_a_collision_during_a_position_move_stops_the_arm(config: ArmConfig) -> None:
    slow = replace(config.joints["j1"], max_velocity=0.36)  # 120 motor RPM, see the README on stalls
    config = replace(config, joints={**config.joints, "j1": slow})
    bus = open_arm_bus(config)
    arm = Arm(config, bus)
    comm = Communicator(arm, frequency=100.0, realtime_priority=None)
    _home_all(arm, comm)
    arm.switch_modes(start=["j1/position"])
    arm.set_command("j1", "position", 0.0)
    comm.run_for(1.5)
    stepper = bus.joint(0x11).stepper
    stepper.add_obstacle(stepper.load_angle() + 30.0, 1)
    with pytest.raises(StalledError):
        comm.run_until(lambda: False, timeout=3)
    assert all(not aj.joint.is_enabled() for aj in arm.joints.values())


def test_open_arm_as_a_context_manager_stops_and_disables_on_ctrl_c(config: ArmConfig, bus: SimBus) -> None:
    from bioscara.hardware import open_arm
    with pytest.raises(KeyboardInterrupt):
        with open_arm(config, bus) as arm:  # configured on entry
            arm.activate()
            motion.home(arm, Communicator(arm, frequency=100.0, realtime_priority=None), ["j4"], timeout=60)
            arm.switch_modes(start=["j4/velocity"])
            arm.set_command("j4", "velocity", -1.0)
            comm = Communicator(arm, frequency=100.0, realtime_priority=None)
            comm.run_for(0.3)
            assert abs(bus.joint(0x14).stepper.driver_rpm()) > 10.0
            raise KeyboardInterrupt  # the user's Ctrl-C in the middle of the script
    joint = bus.joint(0x14)
    assert joint.core.flags & P.FLAG_NOTENABLED and joint.core.qd_set == 0, "stopped and disabled on the way out"
    assert arm.lifecycle is Lifecycle.UNCONFIGURED and not arm["j4"].joint.is_open
    bus.run_for(1.0)
    assert joint.stepper.driver_rpm() == 0.0


class SilentOnce:
    """A motion runner whose host falls silent once, `silence` s of bus time after `after` cycles
    (a loaded machine, a paused script), then cycles on."""

    def __init__(self, comm: Communicator, bus: SimBus, after: int, silence: float) -> None:
        self.comm, self.bus, self.after, self.silence = comm, bus, after, silence

    def run_until(self, predicate, timeout: float) -> None:  # type: ignore[no-untyped-def]
        cycles = 0

        def check() -> bool:
            nonlocal cycles
            cycles += 1
            if cycles == self.after:
                self.bus.sleep(self.silence)
            return bool(predicate())
        self.comm.run_until(check, timeout)


def test_homing_that_the_deadman_ends_says_so_with_the_hosts_silence(arm: Arm, comm: Communicator,
                                                                    bus: SimBus) -> None:
    """Not "homing ended without reaching the end stop" alone: the joint's deadman, after how long
    this host was silent, against its timeout."""
    arm.configure()
    arm.activate()
    with pytest.raises(NotHomedError) as ended:
        motion.home(arm, SilentOnce(comm, bus, after=50, silence=0.3), ["j1"], timeout=60)
    assert re.fullmatch(r"homing ended without reaching the end stop: j1 \(the joint disabled itself: its deadman, "
                        r"after 3\d\d ms without traffic from this host \(its timeout is 100 ms\)\)",
                        ended.value.detail), ended.value.detail
