"""The arm configuration file: the shipped default and one test per kind of problem."""

from __future__ import annotations

import math
import tomllib
from importlib import resources
from pathlib import Path

import pytest

from bioscara.config import ArmConfig, read_config, parse_config, load_config
from bioscara.errors import ConfigError


def default_text() -> str:
    return resources.files("bioscara").joinpath("data/default.toml").read_text()


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "config.toml"
    path.write_text(text)
    return path


def edited(tmp_path: Path, old: str, new: str) -> Path:
    """The default file with the first `old` replaced by `new`."""
    text = default_text()
    assert old in text
    return write(tmp_path, text.replace(old, new, 1))


def problems(path: Path) -> list[str]:
    with pytest.raises(ConfigError) as info:
        read_config(path)
    return info.value.detail.splitlines()


def only_problem(path: Path) -> str:
    lines = problems(path)
    assert len(lines) == 1, lines
    return lines[0]


MINIMAL = """
[joints.j1]
type = "revolute"
address = 0x11
reduction = 35.0
min = -3.0
max = 3.0
stall_threshold = 6
hold_current = 20
drive_current = 20
max_acceleration = 2.0
max_velocity = 1.0

[joints.j1.homing]
speed = 0.03
threshold = 30
current = 15
acceleration = 0.01
"""


def test_default_has_the_real_joint_values() -> None:
    config = read_config()
    assert list(config.joints) == ["j1", "j2", "j3", "j4"]
    j1, j2, j3, j4 = config.joints.values()
    assert (j1.type, j2.type, j3.type, j4.type) == ("revolute", "prismatic", "revolute", "revolute")
    assert [j.address for j in (j1, j2, j3, j4)] == [0x11, 0x12, 0x13, 0x14]
    assert [j.reduction for j in (j1, j2, j3, j4)] == [35.0, -1570.79632679, 24.0, 12.0]
    assert j2.reduction == pytest.approx(-2 * math.pi / 0.004)
    assert [(j.min, j.max) for j in (j1, j2, j3, j4)] == [
        (-3.04647, 3.04647), (-0.0016, 0.338), (-2.62672, 2.62672), (-3.01069, 3.01069)]
    assert [j.stall_threshold for j in (j1, j2, j3, j4)] == [6, 12, 6, 6]
    assert [(j.hold_current, j.drive_current) for j in (j1, j2, j3, j4)] == [(20, 20), (8, 8), (20, 20), (20, 20)]
    assert [(j.max_acceleration, j.max_velocity) for j in (j1, j2, j3, j4)] == [
        (2.0, 1.0), (0.2, 0.03), (14.0, 5.0), (30.0, 10.0)]
    homing = [j.homing for j in (j1, j2, j3, j4)]
    assert [(h.speed, h.threshold, h.current, h.acceleration) for h in homing] == [
        (0.03, 30, 15, 0.01), (0.003, 50, 30, 0.001), (0.05, 25, 10, 0.01), (0.1, 30, 10, 0.1)]
    assert [h.direction for h in homing] == [-1, 1, 1, 1]


def test_default_has_the_real_gripper_bus_and_sim_values() -> None:
    config = read_config()
    g = config.gripper
    assert g is not None
    assert (g.reduction, g.offset, g.min, g.max, g.init_pos) == (3333.3, 0.058, 0.04, 0.120, 0.08)
    assert (g.pwm_chip, g.pwm_channel, g.frequency_hz) == (0, 0, 50.0)
    assert (g.servo_min_us, g.servo_max_us, g.state_file, g.use_mock) == (500.0, 2500.0, "", False)
    assert config.bus.url == config.bus_url == "sim:"
    assert (config.bus.speed_hz, config.bus.attempts, config.bus.use_mock_hardware) == (400_000, 3, False)
    assert config.sim.start == {"j1": -2.95, "j2": 0.333, "j3": 2.55, "j4": 2.95}
    assert config.source.endswith("default.toml")


def test_sim_start_is_inside_the_end_stop_that_homing_runs_into() -> None:
    config = read_config()
    for name, joint in config.joints.items():
        end_stop = joint.min if joint.homing.direction < 0 else joint.max
        assert 0 < abs(config.sim.start[name] - end_stop) < 0.1, name
        assert joint.min < config.sim.start[name] < joint.max


def test_minimal_file_gets_the_optional_defaults(tmp_path: Path) -> None:
    config = read_config(write(tmp_path, MINIMAL))
    assert list(config.joints) == ["j1"]
    assert config.joints["j1"].homing.direction == -1
    assert config.gripper is None
    assert (config.bus.url, config.bus.speed_hz, config.bus.attempts) == ("sim:", 400_000, 3)
    assert (config.sim.seed, config.sim.realtime) == (1, False)
    assert config.sim.start["j1"] == pytest.approx(-3.0 + 0.05)
    assert config.source == str(tmp_path / "config.toml")


def test_joints_come_in_arm_order_whatever_the_file_order(tmp_path: Path) -> None:
    j1 = MINIMAL
    j2 = MINIMAL.replace("j1", "j2").replace("0x11", "0x12")
    assert list(read_config(write(tmp_path, j2 + j1)).joints) == ["j1", "j2"]


def test_use_mock_hardware_selects_the_simulated_bus(tmp_path: Path) -> None:
    config = read_config(write(tmp_path, '[bus]\nurl = "smbus:1"\nuse_mock_hardware = true\n' + MINIMAL))
    assert config.bus.url == "smbus:1"
    assert config.bus_url == "sim:virtual"


def test_parse_config_takes_a_parsed_table() -> None:
    config = parse_config(tomllib.loads(MINIMAL), "inline")
    assert isinstance(config, ArmConfig)
    assert config.source == "inline"


def test_current_out_of_range(tmp_path: Path) -> None:
    path = edited(tmp_path, "hold_current = 8", "hold_current = 120")
    assert only_problem(path) == f"{path}: joints.j2.hold_current = 120 is out of range 0..100"


def test_negative_homing_current(tmp_path: Path) -> None:
    path = edited(tmp_path, "current = 15", "current = -1")
    assert only_problem(path) == f"{path}: joints.j1.homing.current = -1 is out of range 0..100"


def test_threshold_out_of_range(tmp_path: Path) -> None:
    # The original narrowed 256 to a uint8 0 without a word (bug 9.2.11).
    path = edited(tmp_path, "stall_threshold = 12", "stall_threshold = 256")
    assert only_problem(path) == f"{path}: joints.j2.stall_threshold = 256 is out of range 0..255"


def test_homing_threshold_out_of_range(tmp_path: Path) -> None:
    path = edited(tmp_path, "threshold = 50", "threshold = 300")
    assert only_problem(path) == f"{path}: joints.j2.homing.threshold = 300 is out of range 0..255"


def test_min_not_below_max(tmp_path: Path) -> None:
    path = edited(tmp_path, "min = -3.04647\nmax = 3.04647", "min = 3.0\nmax = 1.0")
    assert only_problem(path) == f"{path}: joints.j1.min (3.0) must be below max (1.0)"


def test_unknown_key(tmp_path: Path) -> None:
    path = edited(tmp_path, "max_velocity = 1.0", "max_velocity = 1.0\nmax_velocty = 2.0")
    assert only_problem(path) == f"{path}: unknown key joints.j1.max_velocty (did you mean max_velocity?)"


def test_unknown_joint(tmp_path: Path) -> None:
    path = write(tmp_path, MINIMAL + "[joints.j5]\n")
    assert only_problem(path) == f"{path}: unknown joint joints.j5 (allowed: j1, j2, j3, j4)"


def test_unknown_section(tmp_path: Path) -> None:
    path = write(tmp_path, MINIMAL + "[grippr]\n")
    assert only_problem(path) == f"{path}: unknown key grippr (did you mean gripper?)"


def test_duplicate_address(tmp_path: Path) -> None:
    path = edited(tmp_path, "address = 0x13", "address = 0x12")
    assert only_problem(path) == f"{path}: joints.j3.address 0x12 is already used by j2"


def test_address_out_of_range(tmp_path: Path) -> None:
    path = edited(tmp_path, "address = 0x14", "address = 0x78")
    assert only_problem(path) == f"{path}: joints.j4.address = 0x78 is out of range 0x08..0x77"


def test_wrong_type(tmp_path: Path) -> None:
    path = edited(tmp_path, "reduction = 24.0", 'reduction = "24"')
    assert only_problem(path) == f'{path}: joints.j3.reduction = "24" must be a non-zero number'


def test_float_where_an_integer_is_expected_is_not_narrowed(tmp_path: Path) -> None:
    path = edited(tmp_path, "hold_current = 20", "hold_current = 20.5")
    assert only_problem(path) == f"{path}: joints.j1.hold_current = 20.5 must be an integer 0..100"


def test_wrong_choice(tmp_path: Path) -> None:
    path = edited(tmp_path, 'type = "prismatic"', 'type = "linear"')
    assert only_problem(path) == f'{path}: joints.j2.type = "linear" must be one of "revolute", "prismatic"'


def test_section_that_is_not_a_table(tmp_path: Path) -> None:
    path = write(tmp_path, 'bus = "smbus:1"\n' + MINIMAL)
    assert only_problem(path) == f'{path}: bus = "smbus:1" must be a table'


@pytest.mark.parametrize("literal", ["nan", "inf", "-inf"])
def test_nan_and_inf(tmp_path: Path, literal: str) -> None:
    path = edited(tmp_path, "max = 0.338", f"max = {literal}")
    assert only_problem(path) == f"{path}: joints.j2.max = {literal} must be a finite number"


def test_bool_as_number(tmp_path: Path) -> None:
    path = edited(tmp_path, "drive_current = 8", "drive_current = true")
    assert only_problem(path) == f"{path}: joints.j2.drive_current = true must be an integer 0..100, not a boolean"


def test_bool_as_float(tmp_path: Path) -> None:
    path = edited(tmp_path, "max_velocity = 5.0", "max_velocity = false")
    assert only_problem(path) == f"{path}: joints.j3.max_velocity = false must be a number > 0, not a boolean"


def test_zero_where_positive_is_required(tmp_path: Path) -> None:
    path = edited(tmp_path, "speed = 0.1", "speed = 0")
    assert only_problem(path) == f"{path}: joints.j4.homing.speed = 0 must be > 0"


def test_zero_reduction(tmp_path: Path) -> None:
    path = edited(tmp_path, "reduction = 12.0", "reduction = 0.0")
    assert only_problem(path) == f"{path}: joints.j4.reduction = 0.0 must be non-zero"


def test_bad_homing_direction(tmp_path: Path) -> None:
    path = edited(tmp_path, "direction = -1", "direction = 0")
    assert only_problem(path) == f"{path}: joints.j1.homing.direction = 0 must be one of -1, 1"


def test_bus_values(tmp_path: Path) -> None:
    path = write(tmp_path, '[bus]\nurl = "i2c:1"\nattempts = 0\nspeed_hz = 5_000_000\n' + MINIMAL)
    assert problems(path) == [
        f"{path}: bus.speed_hz = 5000000 is out of range 10000..3400000",
        f"{path}: bus.attempts = 0 is out of range 1..10",
        f'{path}: bus.url = "i2c:1" must start with one of smbus:, blinka:, serial:, sim:',
    ]


def test_gripper_cross_checks(tmp_path: Path) -> None:
    text = (default_text().replace("init_pos = 0.08", "init_pos = 0.2")
            .replace("servo_min_us = 500.0", "servo_min_us = 30000.0").replace("servo_max_us = 2500.0", "servo_max_us = 25000.0"))
    path = write(tmp_path, text)
    assert problems(path) == [
        f"{path}: gripper.init_pos (0.2) must lie within min..max (0.04..0.12)",
        f"{path}: gripper.servo_min_us (30000.0) must be below servo_max_us (25000.0)",
        f"{path}: gripper.servo_max_us (25000.0) must not exceed the PWM period (20000 us at 50 Hz)",
    ]


def test_relative_state_file_is_refused(tmp_path: Path) -> None:
    path = edited(tmp_path, 'state_file = ""', 'state_file = "last_pos.b"')
    assert only_problem(path) == (f'{path}: gripper.state_file = "last_pos.b" must be an absolute path '
                                  "(or empty for the default)")


def test_sim_start_outside_the_joint_range(tmp_path: Path) -> None:
    path = edited(tmp_path, "j1 = -2.95", "j1 = -3.5")
    assert only_problem(path) == f"{path}: sim.start.j1 = -3.5 is outside the joint range -3.04647..3.04647"


def test_sim_start_for_a_joint_that_is_not_configured(tmp_path: Path) -> None:
    path = write(tmp_path, MINIMAL + "[sim.start]\nj2 = 0.1\n")
    assert only_problem(path) == f"{path}: unknown joint sim.start.j2 (allowed: j1)"


def test_sim_payload_and_noise_shape_the_simulated_arm(tmp_path: Path) -> None:
    from bioscara.hardware import open_arm_bus
    path = edited(tmp_path, "payload_kg = 0.0", "payload_kg = 1.0")
    heavy, bare = open_arm_bus(load_config(str(path))), open_arm_bus(load_config())  # in-process simulators
    # J2 carries the payload's weight through its screw: more torque on the motor (sign: down).
    assert heavy.joint(0x12).stepper._load_torque_nm < bare.joint(0x12).stepper._load_torque_nm < 0.0
    path = edited(tmp_path, 'noise = "nominal"', 'noise = "loud"')
    assert only_problem(path) == f'{path}: sim.noise = "loud" must be one of "nominal", "harsh"'


def test_bad_toml(tmp_path: Path) -> None:
    path = write(tmp_path, "[bus]\nurl = 'sim:'\nspeed_hz = = 3\n")
    message = only_problem(path)
    assert message.startswith(f"{path}: not valid TOML (")
    assert "line 3" in message


def test_not_utf8(tmp_path: Path) -> None:
    path = tmp_path / "config.toml"
    path.write_bytes(b"# \xff\n")
    assert only_problem(path).startswith(f"{path}: not valid TOML (not UTF-8 text")


def test_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "config.toml"
    assert only_problem(path) == f"{path}: cannot read the file (No such file or directory)"


def test_missing_required_keys(tmp_path: Path) -> None:
    path = write(tmp_path, MINIMAL.replace("drive_current = 20\n", "").replace("threshold = 30\n", ""))
    assert problems(path) == [
        f"{path}: joints.j1.drive_current is missing (an integer 0..100)",
        f"{path}: joints.j1.homing.threshold is missing (an integer 0..255)",
    ]


def test_missing_homing_table(tmp_path: Path) -> None:
    path = write(tmp_path, MINIMAL.split("[joints.j1.homing]")[0])
    assert only_problem(path) == (f"{path}: joints.j1.homing is missing "
                                  "(a table with speed, threshold, current, acceleration)")


def test_missing_gripper_key(tmp_path: Path) -> None:
    path = edited(tmp_path, "init_pos = 0.08", "")
    assert only_problem(path) == f"{path}: gripper.init_pos is missing (a number)"


def test_no_joints(tmp_path: Path) -> None:
    path = write(tmp_path, "[bus]\n")
    assert only_problem(path) == f"{path}: joints is missing: at least one of the tables joints.j1..joints.j4 is required"


def test_every_problem_is_listed(tmp_path: Path) -> None:
    text = (default_text()
            .replace("hold_current = 8", "hold_current = 120", 1)
            .replace("min = -3.04647\nmax = 3.04647", "min = 3.0\nmax = 1.0", 1)
            .replace("max_velocity = 1.0", "max_velocity = 1.0\nmax_velocty = 2.0", 1)
            .replace("address = 0x13", "address = 0x12", 1)
            .replace("max = 0.338", "max = nan", 1)
            .replace("drive_current = 8", "drive_current = true", 1)
            .replace("init_pos = 0.08", "", 1))
    path = write(tmp_path, text)
    lines = problems(path)
    assert sorted(lines) == sorted([
        f"{path}: joints.j1.min (3.0) must be below max (1.0)",
        f"{path}: unknown key joints.j1.max_velocty (did you mean max_velocity?)",
        f"{path}: joints.j2.max = nan must be a finite number",
        f"{path}: joints.j2.hold_current = 120 is out of range 0..100",
        f"{path}: joints.j2.drive_current = true must be an integer 0..100, not a boolean",
        f"{path}: joints.j3.address 0x12 is already used by j2",
        f"{path}: gripper.init_pos is missing (a number)",
    ])
    assert all(line.startswith(f"{path}: ") for line in lines)


def test_values_the_joint_would_refuse_are_caught_at_load_time(tmp_path) -> None:
    base = resources.files("bioscara").joinpath("data/default.toml").read_text()
    bad = (base.replace("speed = 0.03", "speed = 0.0001", 1)
               .replace("max_velocity = 1.0 ", "max_velocity = 1e9 ", 1))
    path = tmp_path / "arm.toml"
    path.write_text(bad)
    with pytest.raises(ConfigError) as err:
        read_config(path)
    text = str(err.value)
    assert "joints.j1.homing.speed = 0.0001 is 0.0334 motor RPM" in text and "1..250 RPM" in text
    assert "joints.j1.max_velocity = 1000000000.0" in text and "0.001..1e6" in text
