"""End to end through the simulated bus, which runs the real firmware on simulated steppers."""

from __future__ import annotations

import math
import struct
from dataclasses import replace

import pytest

from bioscara import motion
from bioscara.arm import Arm, Lifecycle
from bioscara.bus.sim import SimBus
from bioscara.communicator import Communicator
from bioscara.config import ArmConfig
from bioscara.errors import CommError, NotHomedError, StalledError
from bioscara.firmware import protocol as P
from bioscara.gripper import MockGripper
from bioscara.hardware import open_arm_bus, sim_joint_specs

from conftest import Recorder


def _home_all(arm: Arm, comm: Communicator) -> None:
    arm.configure()
    arm.activate()
    motion.home(arm, comm, timeout=120)


def test_configure_activate_home_move_velocity_stop_shutdown(arm: Arm, comm: Communicator, bus: SimBus,
                                                             config: ArmConfig, tmp_path) -> None:
    _home_all(arm, comm)
    for aj in arm.joints.values():
        end = aj.config.max if aj.config.homing.direction > 0 else aj.config.min
        assert aj.state.home == 1.0
        assert aj.joint.offset == end, "the offset is the end stop homing drove into"
    comm.run_for(0.5)
    for name, aj in arm.joints.items():
        true = bus.joint_position(aj.config.address)
        error_deg = math.degrees(abs(aj.state.position - true) * abs(aj.config.reduction))
        assert error_deg < 2.0, f"{name}: measured position off by {error_deg:.2f} motor degrees"

    targets = {"j1": 0.5, "j2": 0.2, "j3": -1.0, "j4": 1.5}
    final = motion.move_to(arm, comm, targets, tolerance=1e-3, timeout=60)
    for name, target in targets.items():
        assert abs(final[name] - target) <= 1e-3
        true = bus.joint_position(arm[name].config.address)
        assert math.degrees(abs(true - target) * abs(arm[name].config.reduction)) < 3.0, (name, true)

    arm.switch_modes(start=["j1/velocity"], stop=["j1/position"])
    arm.set_command("j1", "velocity", 0.2)
    start = arm["j1"].state.position
    comm.run_for(2.0)
    assert abs(arm["j1"].state.velocity - 0.2) < 0.01
    assert arm["j1"].state.position - start > 0.3
    arm.set_command("j1", "velocity", 0.0)
    comm.run_for(1.0)
    assert abs(arm["j1"].state.velocity) < 1e-3

    assert config.gripper is not None
    gripper = MockGripper(replace(config.gripper, state_file=str(tmp_path / "gripper")), clock=bus.monotonic)
    gripper.init()
    gripper.enable()
    for width in (config.gripper.max, config.gripper.min):
        gripper.set_position(width)
        comm.run_until(lambda: gripper.get_velocity() == 0.0, timeout=5)
        assert gripper.get_position() == pytest.approx(width)
    gripper.disable()

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
    stepper.add_obstacle(stepper.rotor_angle() + 60.0, 1)
    comm.run_until(lambda: arm.fault is not None, timeout=3)
    assert isinstance(arm.fault, StalledError) and arm.fault.joint == "j1"
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
    bus.sleep(0.1)  # the host goes silent
    assert joint.core.flags & P.FLAG_NOTENABLED
    assert joint.stepper.driver_rpm() == 0.0, "the firmware stopped the motor on its own"
    bus.sleep(0.5)
    assert abs(joint.stepper.encoder_rpm()) < 1


def test_releasing_velocity_mode_while_turning_commands_zero(arm: Arm, comm: Communicator, bus: SimBus) -> None:
    _home_all(arm, comm)
    recorder = Recorder(bus)
    arm.switch_modes(start=["j3/velocity"])
    arm.set_command("j3", "velocity", -0.5)
    comm.run_for(1.0)
    recorder.clear()
    arm.switch_modes(stop=["j3/velocity"])
    assert recorder.to(0x13) == [bytes([P.SETRPM]) + struct.pack("<f", 0.0)]
    comm.run_for(1.0)
    assert abs(arm["j3"].state.velocity) < 1e-3, "the joint stopped although reads continue"


def test_a_joint_reboot_is_detected_and_motion_refused_until_rehomed(arm: Arm, comm: Communicator,
                                                                     bus: SimBus) -> None:
    _home_all(arm, comm)
    arm.switch_modes(start=["j2/position"])
    comm.run_for(0.2)
    bus.joint(0x12).power_cycle()
    comm.run_until(lambda: arm.fault is not None, timeout=2)
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
    bus.run_for(2.0)
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
