"""The gripper and its sysfs PWM, against a fake /sys/class/pwm tree in a temp dir and a fake clock."""

from __future__ import annotations

import errno
import logging
import math
import os
import struct
from collections.abc import Callable
from pathlib import Path

import pytest

from bioscara.config import GripperConfig, read_config
from bioscara.errors import (BioscaraError, CommError, IncorrectStateError, InvalidArgumentError, NotEnabledError,
                             NotInitError)
from bioscara.gripper import BaseGripper, Gripper, MockGripper, servo_pulse_us
from bioscara.pwm import SysfsPWM

PERIOD_NS = 20_000_000


class FakeTime:
    """clock() and sleep() in one; sleeping only advances the clock and runs `on_sleep` (the fake kernel)."""

    def __init__(self) -> None:
        self.now = 1000.0
        self.sleeps: list[float] = []
        self.on_sleep: Callable[[], None] | None = None

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.sleeps.append(seconds)
        self.now += seconds
        if self.on_sleep is not None:
            self.on_sleep()


def make_channel(chip: Path, channel: int = 0, duty: int = 0, period: int = 0) -> Path:
    """What the kernel creates on export: pwmN/ with its attribute files."""
    d = chip / f"pwm{channel}"
    d.mkdir()
    (d / "period").write_text(f"{period}\n")
    (d / "duty_cycle").write_text(f"{duty}\n")
    (d / "enable").write_text("0\n")
    return d


@pytest.fixture
def time_() -> FakeTime:
    return FakeTime()


@pytest.fixture
def root(tmp_path: Path, time_: FakeTime) -> Path:
    """A fake /sys/class/pwm with pwmchip0, whose channel 0 appears one poll after "0" is written to export."""
    chip = tmp_path / "sys" / "pwmchip0"
    chip.mkdir(parents=True)
    (chip / "export").write_text("")
    (chip / "unexport").write_text("")

    def kernel() -> None:
        if (chip / "export").read_text() == "0" and not (chip / "pwm0").exists():
            make_channel(chip)

    time_.on_sleep = kernel
    return tmp_path / "sys"


@pytest.fixture
def config(tmp_path: Path) -> GripperConfig:
    return GripperConfig(reduction=3333.3, offset=0.058, min=0.04, max=0.120, init_pos=0.08,
                         state_file=str(tmp_path / "state" / "gripper_position"))


def channel_file(root: Path, name: str) -> str:
    return (root / "pwmchip0" / "pwm0" / name).read_text()


def duty_for(width: float) -> int:
    """The §5.2 formula, written out independently of the code under test."""
    return round(1000 * (3333.3 * (width - 0.058) / 90 * 500 + 1500))


def gripper(config: GripperConfig, root: Path, time_: FakeTime) -> Gripper:
    g = Gripper(config, time_, pwm_root=root, sleep=time_.sleep)
    g.init()
    return g


def saved(config: GripperConfig) -> bytes:
    return Path(config.state_file).read_bytes()


def save_raw(config: GripperConfig, data: bytes) -> None:
    path = Path(config.state_file)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)


# --- PWM values --------------------------------------------------------------------------------------------


def test_enable_exports_and_starts_the_pwm_at_init_pos(config: GripperConfig, root: Path, time_: FakeTime) -> None:
    g = gripper(config, root, time_)
    g.enable()
    assert (root / "pwmchip0" / "export").read_text() == "0"
    assert channel_file(root, "period") == str(PERIOD_NS)
    assert channel_file(root, "duty_cycle") == str(duty_for(0.08))
    assert channel_file(root, "enable") == "1"
    assert g.get_position() == 0.08


@pytest.mark.parametrize(("width", "table_us"), [
    (0.040, 1166.7),  # min
    (0.058, 1500.0),
    (0.080, 1907.4),  # init_pos
    (0.100, 2277.8),
])
def test_duty_cycle_follows_the_original_table(config: GripperConfig, root: Path, time_: FakeTime,
                                               width: float, table_us: float) -> None:
    g = gripper(config, root, time_)
    g.enable()
    g.set_position(width)
    duty = int(channel_file(root, "duty_cycle"))
    assert duty == duty_for(width)
    assert duty / 1000 == pytest.approx(table_us, abs=0.05)


def test_pulse_is_clamped_to_the_servo_range(config: GripperConfig, root: Path, time_: FakeTime) -> None:
    # The original sent 2648.1 us at max width (bug 9.2.17).
    assert servo_pulse_us(config, 0.120) == 2500.0
    g = gripper(config, root, time_)
    g.enable()
    g.set_position(0.120)
    assert channel_file(root, "duty_cycle") == "2500000"


def test_width_is_clamped_to_min_and_max(config: GripperConfig, root: Path, time_: FakeTime) -> None:
    g = gripper(config, root, time_)
    g.enable()
    g.set_position(0.0)
    assert channel_file(root, "duty_cycle") == str(duty_for(0.04))
    time_.now += 10
    assert g.get_position() == 0.04
    g.set_position(1.0)
    time_.now += 10
    assert g.get_position() == 0.120


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_width_is_rejected_and_nothing_is_written(config: GripperConfig, root: Path, time_: FakeTime,
                                                             bad: float) -> None:
    g = gripper(config, root, time_)
    g.enable()
    g.set_position(0.1)
    duty = root / "pwmchip0" / "pwm0" / "duty_cycle"
    duty.write_text("untouched")
    time_.now += 0.05
    with pytest.raises(InvalidArgumentError):
        g.set_position(bad)
    assert duty.read_text() == "untouched"
    assert g.get_position() == pytest.approx(0.09)  # still on its way to 0.1
    time_.now += 1
    assert g.get_position() == 0.1


def test_missing_pwm_chip_names_the_path_and_the_fix(config: GripperConfig, tmp_path: Path, time_: FakeTime) -> None:
    empty = tmp_path / "nopwm"
    empty.mkdir()
    g = gripper(config, empty, time_)
    with pytest.raises(CommError) as info:
        g.enable()
    assert str(empty / "pwmchip0") in str(info.value)
    assert "dtoverlay=pwm" in str(info.value)
    assert "/boot/firmware/config.txt" in str(info.value)
    assert len(time_.sleeps) == 2  # three tries
    assert not g.enabled
    with pytest.raises(NotEnabledError):
        g.set_position(0.1)


def test_failed_sysfs_write_is_a_comm_error_naming_the_file(config: GripperConfig, root: Path,
                                                            time_: FakeTime) -> None:
    g = gripper(config, root, time_)
    g.enable()
    duty = root / "pwmchip0" / "pwm0" / "duty_cycle"
    duty.unlink()
    duty.mkdir()  # opening a directory for writing fails, like a sysfs attribute refusing the value
    with pytest.raises(CommError, match=str(duty)):
        g.set_position(0.1)
    assert g.get_position() == 0.08  # the failed command did not move the estimate


def test_without_init_enable_says_so(config: GripperConfig, root: Path, time_: FakeTime) -> None:
    with pytest.raises(NotInitError):
        Gripper(config, time_, pwm_root=root, sleep=time_.sleep).enable()


# --- sysfs PWM details -------------------------------------------------------------------------------------


def record_writes(monkeypatch: pytest.MonkeyPatch) -> list[tuple[str, int]]:
    writes: list[tuple[str, int]] = []
    real = SysfsPWM._write_file

    def spy(path: Path, value: int) -> None:
        writes.append((path.name, value))
        real(path, value)

    monkeypatch.setattr(SysfsPWM, "_write_file", staticmethod(spy))
    return writes


def test_period_is_written_before_the_duty_cycle(root: Path, time_: FakeTime, monkeypatch: pytest.MonkeyPatch) -> None:
    writes = record_writes(monkeypatch)
    pwm = SysfsPWM(0, 0, 50.0, root, clock=time_, sleep=time_.sleep)
    pwm.start(1_500_000)
    assert writes == [("export", 0), ("period", PERIOD_NS), ("duty_cycle", 1_500_000), ("enable", 1)]


def test_a_long_leftover_duty_cycle_is_shortened_before_the_period(root: Path, time_: FakeTime,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    # The kernel refuses a period shorter than the current duty cycle.
    make_channel(root / "pwmchip0", duty=30_000_000, period=40_000_000)
    writes = record_writes(monkeypatch)
    SysfsPWM(0, 0, 50.0, root, clock=time_, sleep=time_.sleep).start(1_500_000)
    assert writes == [("duty_cycle", 1_500_000), ("period", PERIOD_NS), ("enable", 1)]


def test_close_unexports_only_a_channel_it_exported(root: Path, time_: FakeTime,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    pwm = SysfsPWM(0, 0, 50.0, root, clock=time_, sleep=time_.sleep)
    pwm.start()
    pwm.close()
    assert channel_file(root, "enable") == "0"
    assert (root / "pwmchip0" / "unexport").read_text() == "0"
    writes = record_writes(monkeypatch)
    pwm.close()
    assert writes == []  # idempotent


def test_export_busy_means_already_exported(root: Path, time_: FakeTime, monkeypatch: pytest.MonkeyPatch) -> None:
    real = SysfsPWM._write_file

    def busy_export(path: Path, value: int) -> None:
        if path.name == "export":
            raise CommError("busy") from OSError(errno.EBUSY, os.strerror(errno.EBUSY))
        real(path, value)

    monkeypatch.setattr(SysfsPWM, "_write_file", staticmethod(busy_export))

    def kernel() -> None:
        if not (root / "pwmchip0" / "pwm0").exists():
            make_channel(root / "pwmchip0")

    time_.on_sleep = kernel
    pwm = SysfsPWM(0, 0, 50.0, root, clock=time_, sleep=time_.sleep)
    pwm.start()
    assert channel_file(root, "enable") == "1"
    pwm.close()
    assert (root / "pwmchip0" / "unexport").read_text() == ""  # someone else's export


def test_export_that_never_appears_times_out(root: Path, time_: FakeTime) -> None:
    time_.on_sleep = None  # no kernel
    pwm = SysfsPWM(0, 0, 50.0, root, export_timeout_s=0.5, clock=time_, sleep=time_.sleep)
    with pytest.raises(CommError, match="did not appear within 0.5 s"):
        pwm.start()
    assert 0.5 <= sum(time_.sleeps) < 0.52  # bounded: polled until the deadline, no longer


def test_duty_cycle_is_checked(root: Path, time_: FakeTime) -> None:
    pwm = SysfsPWM(0, 0, 50.0, root, clock=time_, sleep=time_.sleep)
    with pytest.raises(IncorrectStateError):
        pwm.set_duty_ns(1000)
    pwm.start()
    for bad in (-1, PERIOD_NS + 1, True):
        with pytest.raises(InvalidArgumentError):
            pwm.set_duty_ns(bad)
    pwm.set_duty_ns(PERIOD_NS)
    assert channel_file(root, "duty_cycle") == str(PERIOD_NS)


# --- position estimate -------------------------------------------------------------------------------------


def test_estimate_moves_toward_the_command_at_servo_speed(config: GripperConfig, time_: FakeTime) -> None:
    g = MockGripper(config, time_)
    g.enable()
    assert (g.get_position(), g.get_velocity()) == (0.08, 0.0)
    g.set_position(0.1)
    assert (g.get_position(), g.get_velocity()) == (0.08, 0.2)
    time_.now += 0.05
    assert g.get_position() == pytest.approx(0.09)
    g.set_position(0.04)  # reverses from where it is
    assert g.get_position() == pytest.approx(0.09)
    assert g.get_velocity() == -0.2
    time_.now += 0.25
    assert (g.get_position(), g.get_velocity()) == (0.04, 0.0)


def test_velocity_needs_no_time_to_pass(config: GripperConfig, time_: FakeTime) -> None:
    g = MockGripper(config, time_)
    g.enable()
    g.set_position(0.1)
    g.set_position(0.1)  # same instant: the original divided by a zero period here
    assert g.get_velocity() == 0.2


def test_position_is_unknown_until_enabled(config: GripperConfig, time_: FakeTime) -> None:
    g = MockGripper(config, time_)
    with pytest.raises(NotEnabledError):
        g.get_position()
    with pytest.raises(NotEnabledError):
        g.set_position(0.1)


# --- persistence -------------------------------------------------------------------------------------------


def test_position_survives_disable_and_enable(config: GripperConfig, root: Path, time_: FakeTime) -> None:
    g = gripper(config, root, time_)
    g.enable()
    g.set_position(0.1)
    time_.now += 1
    g.close()
    assert channel_file(root, "enable") == "0"
    assert saved(config) == struct.pack("<f", 0.1)
    g2 = gripper(config, root, time_)
    g2.enable()
    assert g2.get_position() == pytest.approx(0.1)
    assert channel_file(root, "duty_cycle") == str(duty_for(struct.unpack("<f", struct.pack("<f", 0.1))[0]))


def test_disable_mid_motion_saves_where_the_servo_is(config: GripperConfig, time_: FakeTime) -> None:
    g = MockGripper(config, time_)
    g.enable()
    g.set_position(0.12)
    time_.now += 0.1
    g.disable()
    assert struct.unpack("<f", saved(config))[0] == pytest.approx(0.1)
    time_.now += 1
    assert g.get_position() == pytest.approx(0.1)


def test_a_saved_limit_comes_back_exactly(config: GripperConfig, time_: FakeTime) -> None:
    # 0.04 as float32 is slightly below 0.04; it must not be refused as out of range.
    g = MockGripper(config, time_)
    g.enable()
    g.set_position(0.04)
    time_.now += 1
    g.close()
    g.enable()
    assert g.get_position() == 0.04


@pytest.mark.parametrize(("data", "why"), [
    (b"", "0 bytes"),
    (b"\x00\x00", "2 bytes"),
    (struct.pack("<f", 0.1) + b"\x00", "more than 4 bytes"),
    (struct.pack("<f", math.nan), "outside"),
    (struct.pack("<f", math.inf), "outside"),
    (struct.pack("<f", 0.5), "outside"),
    (struct.pack("<f", 0.0), "outside"),  # what the original saved when disabled before enabling
])
def test_bad_state_file_falls_back_to_init_pos(config: GripperConfig, time_: FakeTime, caplog: pytest.LogCaptureFixture,
                                               data: bytes, why: str) -> None:
    save_raw(config, data)
    g = MockGripper(config, time_)
    with caplog.at_level(logging.WARNING, logger="bioscara.gripper"):
        g.enable()
    assert g.get_position() == 0.08
    assert why in caplog.text and config.state_file in caplog.text


def test_missing_or_unreadable_state_file_falls_back_to_init_pos(config: GripperConfig, time_: FakeTime,
                                                                 caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING, logger="bioscara.gripper"):
        assert MockGripper(config, time_).load_position() == 0.08
        assert "no saved gripper position" in caplog.text
        Path(config.state_file).mkdir(parents=True)
        assert MockGripper(config, time_).load_position() == 0.08
        assert "cannot read" in caplog.text


@pytest.mark.parametrize("crash_in", ["fsync", "replace"])
def test_persistence_survives_an_interrupted_write(config: GripperConfig, time_: FakeTime,
                                                   monkeypatch: pytest.MonkeyPatch, crash_in: str) -> None:
    g = MockGripper(config, time_)
    g.enable()
    g.set_position(0.1)
    time_.now += 1
    g.disable()
    before = saved(config)

    g.enable()
    g.set_position(0.05)
    time_.now += 1

    def crash(*args: object) -> None:
        raise OSError(errno.EIO, "simulated crash")

    monkeypatch.setattr(os, crash_in, crash)
    with pytest.raises(BioscaraError, match=config.state_file):
        g.disable()
    monkeypatch.undo()

    assert saved(config) == before
    assert os.listdir(Path(config.state_file).parent) == ["gripper_position"]  # no temp file left
    g2 = MockGripper(config, time_)
    g2.enable()
    assert g2.get_position() == pytest.approx(0.1)


def test_a_save_killed_half_way_leaves_nothing_behind_after_the_next_save(config: GripperConfig,
                                                                          time_: FakeTime) -> None:
    def killed_save(width: float) -> None:
        """A process that is killed between writing its temporary file and renaming it."""
        pid = os.fork()
        if pid == 0:
            os.replace = lambda *args: os._exit(9)  # type: ignore[assignment]
            g = MockGripper(config, time_)
            g.enable()
            g.set_position(width)
            g.disable()
            os._exit(0)
        os.waitpid(pid, 0)

    directory = Path(config.state_file).parent
    for width in (0.05, 0.06, 0.07):
        killed_save(width)
    left = [name for name in os.listdir(directory) if name.endswith(".tmp")]
    assert len(left) == 1, "each killed save removed the one before it; the last one is left"
    g = MockGripper(config, time_)
    g.enable()
    g.set_position(0.1)
    time_.now += 1
    g.disable()
    assert os.listdir(directory) == ["gripper_position"], "the next save removed them"
    assert Path(config.state_file).stat().st_mode & 0o777 == 0o600


def test_pwm_is_off_even_when_saving_fails(config: GripperConfig, root: Path, time_: FakeTime,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    g = gripper(config, root, time_)
    g.enable()

    def crash(*args: object) -> None:
        raise OSError(errno.ENOSPC, "no space")

    monkeypatch.setattr(os, "replace", crash)
    with pytest.raises(BioscaraError):
        g.close()
    assert channel_file(root, "enable") == "0"
    g.close()  # idempotent


def test_default_state_files_live_in_the_xdg_state_dir(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    gc = read_config().gripper
    assert gc is not None and gc.state_file == ""
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "xdg"))
    assert Gripper(gc).state_file == tmp_path / "xdg" / "bioscara" / "gripper_position"
    assert MockGripper(gc).state_file == tmp_path / "xdg" / "bioscara" / "mock_gripper_position"
    monkeypatch.setenv("XDG_STATE_HOME", "relative/dir")  # the spec says to ignore relative paths
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert Gripper(gc).state_file == tmp_path / "home" / ".local" / "state" / "bioscara" / "gripper_position"


def test_context_manager_disables_saves_and_releases(config: GripperConfig, root: Path, time_: FakeTime) -> None:
    with Gripper(config, time_, pwm_root=root, sleep=time_.sleep) as g:
        g.enable()
        g.set_position(0.06)
        time_.now += 1
    assert channel_file(root, "enable") == "0"
    assert (root / "pwmchip0" / "unexport").read_text() == "0"
    assert struct.unpack("<f", saved(config))[0] == pytest.approx(0.06)
    g.close()


def test_base_gripper_init_and_deinit_do_nothing(config: GripperConfig, time_: FakeTime) -> None:
    g = BaseGripper(config, time_)
    g.init()
    g.enable()
    g.deinit()
    assert g.enabled
    g.close()
    assert not g.enabled
