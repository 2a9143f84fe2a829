"""`bioscara calibrate JOINT` on the simulated arm: what it measures against the simulator's truth,
what it stores on the joint (over the bus, or as on a real arm over the board's USB serial port),
and what it refuses."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from bioscara import cli, encoder_calibration, firmware_flash, mpboard
from bioscara.bus.sim import SimBus
from bioscara.errors import ConfigError
from tests.test_flash import FakeBoard


def run(capsys: pytest.CaptureFixture[str], *argv: str, bus: SimBus) -> tuple[int, str, str]:
    code = cli.main(list(argv), bus=bus)
    out, err = capsys.readouterr()
    return code, out, err


def true_error_deg(bus: SimBus, address: int) -> float:
    """The largest |encoder reading - rotor| the firmware sees over a motor turn (the simulator's
    truth, noise left out), about its mean."""
    stepper = bus.joint(address).stepper
    errors = [stepper.encoder_error(i * 0.5) for i in range(720)]
    mean = sum(errors) / len(errors)
    return max(abs(e - mean) for e in errors)


def test_calibrate_removes_most_of_the_encoder_error_the_firmware_sees(
        capsys: pytest.CaptureFixture[str], bus: SimBus) -> None:
    assert run(capsys, "home", "j1", "j3", bus=bus)[0] == 0
    before = {addr: true_error_deg(bus, addr) for addr in (0x11, 0x13)}
    assert abs(before[0x11] - before[0x13]) > 0.02, "each joint's sensor has its own error"
    code, out, err = run(capsys, "calibrate", "j1", "--json", bus=bus)
    assert code == 0, err
    result = json.loads(out)
    after = true_error_deg(bus, 0x11)
    assert after <= 0.1 * before[0x11], (before[0x11], after)
    assert true_error_deg(bus, 0x13) == before[0x13], "the other joints are left alone"
    # What the command says it measured agrees with the truth.
    assert abs(result["error_before_deg"] - before[0x11]) <= 0.1 * before[0x11], (result, before)
    assert result["error_after_deg"] <= 0.1 * result["error_before_deg"]
    # The table is in the joint's configuration file, which its firmware read at the reboot.
    stored = json.loads(bus.joint_config_file(0x11))["encoder"]["correction"]
    assert stored == result["table_millideg"] and len(stored) == encoder_calibration.TABLE_SIZE
    assert list(bus.joint(0x11).cfg.encoder.correction) == stored
    assert bus.joint(0x11).core.cfg.encoder.correction == tuple(stored)
    # It survives another reboot, and the joint was homed again after the first.
    assert run(capsys, "info", "j1", "--json", bus=bus)[0] == 0
    bus.reboot_joint(0x11)
    assert true_error_deg(bus, 0x11) == after


def test_calibrating_again_refines_the_table_in_use(capsys: pytest.CaptureFixture[str], bus: SimBus) -> None:
    assert run(capsys, "home", "j3", bus=bus)[0] == 0
    before = true_error_deg(bus, 0x13)
    assert run(capsys, "calibrate", "j3", bus=bus)[0] == 0
    code, out, err = run(capsys, "calibrate", "j3", bus=bus)
    assert code == 0, err
    assert true_error_deg(bus, 0x13) <= 0.1 * before
    assert "encoder error over a motor turn" in out and "deg after calibration" in out


def test_calibrate_refuses_a_joint_that_is_not_homed_in_one_line_and_stores_nothing(
        capsys: pytest.CaptureFixture[str], bus: SimBus) -> None:
    stored = bus.joint_config_file(0x11)
    code, _, err = run(capsys, "calibrate", "j1", bus=bus)
    assert code == 1 and "not homed: run `bioscara home j1` first" in err and len(err.strip().splitlines()) == 1
    assert bus.joint_config_file(0x11) == stored


@pytest.mark.parametrize("correction, message", [
    ([0] * 31, "encoder.correction must be a list of 16, 32 or 64 integers (motor millidegrees), got 31"),
    ([9000] * 32, "encoder.correction = 9000 is out of range -5000..5000"),
    ("[1, 2]", "got '[1, 2]'"),
])
def test_a_hostile_table_is_refused_before_it_reaches_the_joint(bus: SimBus, correction: object,
                                                                message: str) -> None:
    stored = bus.joint_config_file(0x12)
    data = json.loads(stored)
    data["encoder"] = {"correction": correction}
    with pytest.raises(ConfigError, match=re.escape(message)):
        bus.write_joint_config_file(0x12, json.dumps(data).encode())
    with pytest.raises(ConfigError, match=re.escape(message)):
        encoder_calibration.with_correction(stored, correction, "j2's configuration file")  # type: ignore[arg-type]
    assert bus.joint_config_file(0x12) == stored
    bus.reboot_joint(0x12)
    assert bus.joint(0x12).core.cfg.encoder.correction == ()


def test_the_fit_finds_a_known_error_and_the_tables_combine() -> None:
    times = [i * 0.01 for i in range(2000)]
    sweeps = []
    for direction in (1, -1):
        degrees = [direction * 60.0 * t + 0.3 * direction for t in times]
        sensed = [d + 0.5 * math.sin(math.radians(d + 40.0 + 17.0)) for d in degrees]
        sweeps.append(encoder_calibration.Sweep(direction, np.array(times),
                                                np.array(sensed)))
    fit = encoder_calibration.fit(sweeps, 40.0)
    assert abs(fit.peak_deg - 0.5) < 0.01 and fit.residual_rms_deg < 0.01
    table = fit.table_millideg(16)
    assert abs(table[0] - 500 * math.sin(math.radians(17.0))) <= 10
    assert encoder_calibration.combined(table, [10] * 16) == [v + 10 for v in table]
    assert encoder_calibration.combined([100] * 16, [0] * 32) == [100] * 32


# ---- a real arm: the table goes over the joint's USB serial port (`--port`) ----

class SimJointsBoard(FakeBoard):
    """The board of a simulated joint, as `calibrate --port` sees it: its /joint_config.json is the
    joint's configuration file, which its firmware reads when the board resets."""

    def __init__(self, bus: SimBus, address: int, port: Path) -> None:
        super().__init__(files={firmware_flash.CONFIG_PATH: bus.joint_config_file(address)})
        self.port = str(port)
        self._bus, self._address = bus, address

    def reset(self) -> None:
        super().reset()
        self._bus.write_joint_config_file(self._address, self.files[firmware_flash.CONFIG_PATH])
        self._bus.joint(self._address).power_cycle()


@pytest.fixture
def i2c_only(bus: SimBus) -> SimBus:
    """The simulated arm as a real bus is: the joints' I2C, not their configuration files."""
    bus.reaches_config_files = False
    return bus


def board_on(monkeypatch: pytest.MonkeyPatch, tmp_path: Path, bus: SimBus, address: int) -> SimJointsBoard:
    port = tmp_path / "ttyACM0"
    port.touch()
    board = SimJointsBoard(bus, address, port)
    monkeypatch.setattr(mpboard, "open_board", lambda path: board if path == board.port else pytest.fail(path))
    return board


def test_on_a_real_bus_the_table_goes_into_the_boards_config_file_over_its_port(
        capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path, i2c_only: SimBus) -> None:
    board = board_on(monkeypatch, tmp_path, i2c_only, 0x11)
    assert run(capsys, "home", "j1", bus=i2c_only)[0] == 0
    before = true_error_deg(i2c_only, 0x11)
    code, out, err = run(capsys, "calibrate", "j1", "--port", board.port, "--json", bus=i2c_only)
    assert code == 0, err
    result = json.loads(out)
    stored = json.loads(board.files[firmware_flash.CONFIG_PATH])["encoder"]["correction"]
    assert stored == result["table_millideg"] and len(stored) == encoder_calibration.TABLE_SIZE
    # Written beside the old file, renamed over it, then the board reset; nothing else touched.
    assert board.log == [("write", "/joint_config.json.new"), ("rename", "/joint_config.json.new"), ("reset", "")]
    assert set(board.files) == {firmware_flash.CONFIG_PATH}
    # The firmware booted with it, and the command measured through it after homing again.
    assert i2c_only.joint(0x11).core.cfg.encoder.correction == tuple(stored)
    assert true_error_deg(i2c_only, 0x11) <= 0.1 * before
    assert result["stored"] is True and result["error_after_deg"] <= 0.1 * result["error_before_deg"]


def test_on_a_real_bus_without_a_port_the_table_is_measured_and_printed_not_stored(
        capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, i2c_only: SimBus) -> None:
    monkeypatch.setattr(mpboard, "open_board", lambda path: pytest.fail("no board is opened"))
    stored = i2c_only.joint_config_file(0x13)
    assert run(capsys, "home", "j3", bus=i2c_only)[0] == 0
    code, out, err = run(capsys, "calibrate", "j3", bus=i2c_only)
    assert code == 0, err
    assert "measured table (motor millidegrees): [" in out
    assert out.strip().splitlines()[-1].startswith("not stored: ") and "`bioscara calibrate j3 --port PORT`" in out
    assert i2c_only.joint_config_file(0x13) == stored


def test_another_joints_board_on_the_port_is_refused_in_one_line_and_nothing_is_written(
        capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path, i2c_only: SimBus) -> None:
    board = board_on(monkeypatch, tmp_path, i2c_only, 0x12)  # j2's board, on the port given for j1
    files = dict(board.files)
    assert run(capsys, "home", "j1", bus=i2c_only)[0] == 0
    code, _, err = run(capsys, "calibrate", "j1", "--port", board.port, bus=i2c_only)
    assert code == 1 and len(err.strip().splitlines()) == 1
    assert f"{board.port} is j2's board (I2C 0x12), not j1's (0x11): nothing was written" in err
    assert board.files == files and board.log == []


@pytest.mark.parametrize("unplugged_at", ["write", "rename"])
def test_a_port_that_vanishes_leaves_the_config_file_whole_and_says_so_in_one_line(
        capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path, i2c_only: SimBus,
        unplugged_at: str) -> None:
    board = board_on(monkeypatch, tmp_path, i2c_only, 0x11)
    config = board.files[firmware_flash.CONFIG_PATH]
    board.unplugged_at = unplugged_at
    assert run(capsys, "home", "j1", bus=i2c_only)[0] == 0
    code, _, err = run(capsys, "calibrate", "j1", "--port", board.port, bus=i2c_only)
    assert code == 1 and len(err.strip().splitlines()) == 1
    assert f"on {board.port} failed: [Errno 5] Input/output error" in err
    assert {"write": "/joint_config.json is unchanged",
            "rename": "/joint_config.json is whole, the old one or the new one: run it again"}[unplugged_at] in err
    assert board.files[firmware_flash.CONFIG_PATH] == config and ("reset", "") not in board.log


def test_a_missing_port_an_s32_the_bridges_port_and_a_port_on_the_simulator_are_refused_before_the_motor_turns(
        capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path, bus: SimBus) -> None:
    monkeypatch.setattr(mpboard, "open_board", lambda path: pytest.fail("no board is opened"))
    assert run(capsys, "home", "j1", bus=bus)[0] == 0
    rotor = bus.joint(0x11).stepper.load_angle()
    code, _, err = run(capsys, "calibrate", "j1", "--port", "/dev/ttyACM0", bus=bus)
    assert code == 2 and "reaches the simulated joints' configuration files itself: give no --port" in err
    bus.reaches_config_files = False
    missing = str(tmp_path / "ttyACM9")
    code, _, err = run(capsys, "calibrate", "j1", "--port", missing, bus=bus)
    assert code == 1 and f"serial port {missing} does not exist" in err and len(err.strip().splitlines()) == 1
    code, _, err = run(capsys, "calibrate", "j1", "--port", missing, "--board", "s32", bus=bus)
    assert code == 2 and "an S32 keeps its configuration in flash, which calibrate cannot write yet" in err
    monkeypatch.setattr(bus, "describe", lambda: f"serial:{missing}")
    code, _, err = run(capsys, "calibrate", "j1", "--port", missing, bus=bus)
    assert code == 2 and f"{missing} is the HIL bridge the bus runs over" in err
    assert bus.joint(0x11).stepper.load_angle() == rotor
