"""`bioscara calibrate JOINT` on the simulated arm: what it measures against the simulator's truth,
what it stores on the joint, and what it refuses."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from bioscara import cli, encoder_calibration
from bioscara.bus.sim import SimBus
from bioscara.errors import ConfigError


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
