"""The `bioscara` command against the simulator: what users type, what they get back."""

from __future__ import annotations

from bioscara.firmware.spec import protocol as P

import csv
import json
import re

import pytest

from bioscara import cli
from bioscara.bus.sim import SimBus


def run(capsys: pytest.CaptureFixture[str], *argv: str, bus: SimBus | None = None) -> tuple[int, str, str]:
    code = cli.main(list(argv), bus=bus)
    out, err = capsys.readouterr()
    return code, out, err


def test_scan_finds_four_joints_with_identity(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "scan", "--json")
    found = json.loads(out)
    assert code == 0
    assert [(d["address"], d["joint"], d["joint_id"]) for d in found] == [
        (0x11, "j1", 1), (0x12, "j2", 2), (0x13, "j3", 3), (0x14, "j4", 4)]
    assert all(d["spec_matches"] and d["firmware"] == "0.1.0" for d in found)


def test_scan_reports_a_spec_hash_mismatch(capsys: pytest.CaptureFixture[str], bus: SimBus) -> None:
    bus.joint(0x13).core.cached_reply(0x30)[5:9] = b"\xde\xad\xbe\xef"  # as if built from another spec
    code, out, _ = run(capsys, "scan", "--json", bus=bus)
    j3 = next(d for d in json.loads(out) if d["address"] == 0x13)
    assert code == 1 and not j3["spec_matches"] and "different protocol specs" in j3["problems"][0]


def test_home_all_then_move_reaches_the_target(capsys: pytest.CaptureFixture[str], bus: SimBus) -> None:
    code, out, _ = run(capsys, "home", "all", "--json", bus=bus)
    assert code == 0 and all(j["homed"] for j in json.loads(out.splitlines()[-1])["joints"])
    code, out, _ = run(capsys, "move", "j3", "1.25", "--json", bus=bus)
    assert code == 0 and abs(json.loads(out)["position"] - 1.25) <= 1e-3
    assert abs(bus.joint_position(0x13) - 1.25) < 0.005, "the simulated joint is really there"


def test_move_enforces_limits_and_homing(capsys: pytest.CaptureFixture[str], bus: SimBus) -> None:
    code, _, err = run(capsys, "move", "j1", "4.0", bus=bus)
    assert code == 2 and "4 rad is outside the limits -3.04647..3.04647 rad" in err and len(err.strip().splitlines()) == 1
    code, _, err = run(capsys, "move", "j1", "90", bus=bus)
    assert code == 2 and "positions are in rad: 90 degrees is 1.57080 rad" in err
    code, _, err = run(capsys, "move", "J2", "150", bus=bus)
    assert code == 2 and "positions are in m: 150 mm is 0.15 m" in err
    code, _, err = run(capsys, "move", "j1", "1.0", bus=bus)
    assert code == 1 and "run `bioscara home j1` first" in err


def test_monitor_records_rows_with_the_expected_columns_and_plot_renders(
        capsys: pytest.CaptureFixture[str], tmp_path) -> None:
    record = tmp_path / "trace.csv"
    code, out, _ = run(capsys, "monitor", "--samples", "25", "--rate", "50", "--record", str(record), "--json")
    lines = [json.loads(line) for line in out.splitlines()]
    assert code == 0 and len(lines) == 26 and lines[-1]["summary"]["rows"] == 25, "one line per sample, then a summary"
    assert [j["joint"] for j in lines[0]["joints"]] == ["j1", "j2", "j3", "j4"]
    assert lines[0]["joints"][1] == {"joint": "j2", "address": 0x12, "unit": "m", "position": None,
                                     "velocity": lines[0]["joints"][1]["velocity"], "flags": ["NOTHOMED", "NOTENABLED"]}
    with open(record) as f:
        meta = json.loads(f.readline()[2:])
        rows = list(csv.DictReader(f))
    assert meta["spec_hash"] and meta["rate_hz"] == 50.0
    assert len(rows) == 25 and list(rows[0]) == ["time", "cycle"] + [
        f"j{i}/{v}" for i in range(1, 5) for v in ("position", "velocity", "flags", "home")] + ["fault"]
    assert float(rows[-1]["time"]) - float(rows[0]["time"]) == pytest.approx(24 / 50, abs=1e-3)
    code, out, _ = run(capsys, "plot", str(record), "--json")
    png = json.loads(out)["png"]
    assert json.loads(out)["axes"] == ["position (rad)", "position (m)", "velocity (rad/s)", "velocity (m/s)"]
    with open(png, "rb") as f:
        assert f.read(8) == b"\x89PNG\r\n\x1a\n"


def test_monitor_records_json_lines(capsys: pytest.CaptureFixture[str], tmp_path) -> None:
    record = tmp_path / "trace.jsonl"
    run(capsys, "monitor", "--samples", "3", "--record", str(record))
    lines = [json.loads(line) for line in record.read_text().splitlines()]
    assert "spec_hash" in lines[0]["meta"] and len(lines) == 4
    assert set(lines[1]["values"]) >= {"j1/position", "j4/flags"}


def test_enable_disable_and_stop(capsys: pytest.CaptureFixture[str], bus: SimBus) -> None:
    code, out, _ = run(capsys, "enable", "j1", "J2", "--json", bus=bus)
    assert code == 0 and json.loads(out) == [
        {"joint": "j1", "address": 0x11, "ok": True, "result": "enabled (not homed)"},
        {"joint": "j2", "address": 0x12, "ok": True, "result": "enabled (not homed)"}]
    assert bus.joint(0x11).core.stallguard, "stall detection on with the configured threshold"
    code, out, _ = run(capsys, "stop", "--json", bus=bus)
    assert code == 0 and {d["result"] for d in json.loads(out)} == {"stopped"}
    code, out, _ = run(capsys, "disable", bus=bus)
    assert code == 0 and all(bus.joint(a).core.flags & 0x08 for a in (0x11, 0x12, 0x13, 0x14))


def test_info_reports_identity_and_flags(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "--json", "info", "J4")
    info = json.loads(out)
    assert code == 0 and info["joint"] == "j4" and info["address"] == 0x14 and info["unit"] == "rad"
    assert info["joint_id"] == 4 and info["flags"] == ["NOTHOMED", "NOTENABLED"] and info["position"] is None
    code, out, _ = run(capsys, "info", "j2")
    text = " ".join(re.sub("[│┃]", " ", out).split())
    assert "limits -0.0016..0.338 m" in text and "position not homed" in text
    assert re.search(r"velocity [+-]\d\.\d{5} m/s", text)
    assert "{" not in out and "e-05" not in out, "no Python reprs"


def test_scan_and_info_only_read_they_switch_no_protocol(capsys: pytest.CaptureFixture[str], bus: SimBus) -> None:
    code, out, _ = run(capsys, "scan", "--json", bus=bus)
    assert code == 0 and all(d["protocols"] == "legacy+v2" for d in json.loads(out))
    code, out, _ = run(capsys, "info", "j2", "--json", bus=bus)
    info = json.loads(out)
    assert code == 0 and info["commanded_by"] is None and info["spec_matches"]
    assert bus.joint(0x12).protocol == 1, "info reads the legacy map and switches nothing"
    code, _, err = run(capsys, "info", "j2", "--protocol", "v2", bus=bus)
    assert code == 2 and "only reads" in err and bus.joint(0x12).protocol == 1
    code, _, err = run(capsys, "move", "j2", "0.1", "--protocol", "v3", bus=bus)
    assert code == 2 and "invalid choice: 'v3'" in err


def test_errors_are_one_line_and_non_zero(capsys: pytest.CaptureFixture[str], tmp_path) -> None:
    bad = tmp_path / "arm.toml"
    bad.write_text("[bus]\nattempts = 99\n")
    code, out, err = run(capsys, "scan", "--config", str(bad))
    assert code == 2 and "bus.attempts = 99 is out of range 1..10" in err and "Traceback" not in err + out
    code, _, err = run(capsys, "info", "j7")
    assert code == 2 and err.strip().count("\n") == 0 and "no joint 'j7'" in err
    code, _, err = run(capsys, "scan", "--bus", "smbus:/dev/i2c-99")
    assert code == 1 and "cannot open /dev/i2c-99" in err and "Traceback" not in err
    code, _, err = run(capsys, "scan", "--bus", "carrier-pigeon:")
    assert code == 2 and "unknown bus 'carrier-pigeon:'" in err


def test_a_moved_joint_keeps_holding_after_the_command_exits(capsys: pytest.CaptureFixture[str],
                                                             bus: SimBus) -> None:
    run(capsys, "home", "j3", bus=bus)
    assert run(capsys, "move", "j3", "1.25", bus=bus)[0] == 0
    bus.sleep(1.0)  # nobody talks to the joint any more
    assert not bus.joint(0x13).core.flags & 0x08, "still enabled: the deadman had nothing to stop"
    assert abs(bus.joint_position(0x13) - 1.25) < 0.005


def test_ctrl_c_while_homing_sends_stop(capsys: pytest.CaptureFixture[str], bus: SimBus,
                                        monkeypatch: pytest.MonkeyPatch) -> None:
    from bioscara.communicator import Communicator
    from conftest import Recorder
    recorder = Recorder(bus)
    cycle = Communicator.cycle

    def interrupted(self: Communicator):  # type: ignore[no-untyped-def]
        if self.stats.cycles == 30:
            raise KeyboardInterrupt
        return cycle(self)
    monkeypatch.setattr(Communicator, "cycle", interrupted)
    code, _, err = run(capsys, "home", "j1", bus=bus)
    assert code == 130 and "interrupted" in err
    # The command byte leads a legacy frame and a v2 mailbox alike.
    commands = [w[0] for w in recorder.to(0x11) if w]
    assert P.HOME in commands, "homing had started"
    assert P.STOP in commands[commands.index(P.HOME):], "then STOP"
    assert bus.joint(0x11).core.task_name is None, "the firmware aborted the homing"


def test_bad_rates_are_one_line_errors_and_touch_nothing(capsys: pytest.CaptureFixture[str],
                                                        bus: SimBus) -> None:
    for argv in (("monitor", "--rate", "0"), ("home", "j1", "--rate", "0"), ("monitor", "--rate", "20000")):
        code, out, err = run(capsys, *argv, bus=bus)
        assert code == 2 and "Traceback" not in err + out and len(err.strip().splitlines()) == 1
        assert "cycle rate must be in (0, 10000] Hz" in err or "must be > 0 Hz" in err
    assert all(bus.joint(a).core.flags & 0x08 for a in (0x11, 0x12, 0x13, 0x14)), "nothing was enabled"


def test_disable_carries_on_past_a_missing_joint(capsys: pytest.CaptureFixture[str], bus: SimBus) -> None:
    run(capsys, "enable", bus=bus)
    bus.joint(0x11).connected = False
    code, out, _ = run(capsys, "disable", "--json", bus=bus)
    results = {d["joint"]: d for d in json.loads(out)}
    assert code == 1 and not results["j1"]["ok"] and results["j4"]["result"].startswith("disabled")
    assert "I2C 0x11" in results["j1"]["error"], "names the address (and the entry the joint)"
    assert all(bus.joint(a).core.flags & 0x08 for a in (0x12, 0x13, 0x14))


def test_monitor_carries_on_when_a_joint_goes_missing(capsys: pytest.CaptureFixture[str], bus: SimBus,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    from bioscara.arm import Arm
    configure = Arm.configure

    def configure_then_unplug_j1(self: Arm) -> None:
        configure(self)
        bus.joint(0x11).connected = False
    monkeypatch.setattr(Arm, "configure", configure_then_unplug_j1)
    code, out, _ = run(capsys, "monitor", "--samples", "5", "--json", bus=bus)
    summary = json.loads(out.splitlines()[-1])["summary"]
    assert code == 1 and summary["samples"] == 5 and summary["errors"] == 5


def test_plot_refuses_what_is_not_a_recording(capsys: pytest.CaptureFixture[str], tmp_path) -> None:
    for name, text in (("a.jsonl", '{"meta": {"bus": "sim:"}}\n'), ("b.jsonl", '{"meta": {"joints": ["j1"], '
                       '"bus": "sim:", "spec_hash": "0", "rate_hz": 1}}\n[1, 2]\n'), ("c.csv", "time,cycle\n1,2\n")):
        path = tmp_path / name
        path.write_text(text)
        code, out, err = run(capsys, "plot", str(path))
        assert code == 2 and "not a bioscara recording" in err and "Traceback" not in err + out


def _bus_with(config, **changes) -> SimBus:  # type: ignore[no-untyped-def]
    """The simulated arm with some joints' firmware moved: changes = {"J4": 0x15} or {"J4": None}."""
    from dataclasses import replace as change

    from bioscara.hardware import sim_joint_specs
    specs = []
    for spec in sim_joint_specs(config):
        if spec.firmware_joint in changes:
            if changes[spec.firmware_joint] is None:
                continue
            spec = change(spec, address=changes[spec.firmware_joint])
        specs.append(spec)
    return SimBus(specs)


def test_scan_is_a_bring_up_check(capsys: pytest.CaptureFixture[str], config, tmp_path) -> None:  # type: ignore[no-untyped-def]
    code, out, _ = run(capsys, "scan", "--json", bus=_bus_with(config, J4=None))
    j4 = next(e for e in json.loads(out) if e["joint"] == "j4")
    assert code == 1 and j4["kind"] == "missing" and not j4["answers"] and j4["address"] == 0x14
    assert "j4 is configured at 0x14 but nothing answers there" in j4["problems"][0]
    code, out, _ = run(capsys, "scan", "--json", bus=_bus_with(config, J4=0x15))
    entries = {e["address"]: e for e in json.loads(out)}
    assert code == 1 and "IDENTITY says j4 answers at 0x15" in entries[0x14]["problems"][0]
    assert "misaddressed: j4 (by IDENTITY) answers here, but the configuration has it at 0x14" in entries[0x15]["problems"][0]
    code, out, _ = run(capsys, "scan", "--json", bus=_bus_with(config, J4=0x13, J3=0x40))
    entries = {e["address"]: e for e in json.loads(out)}
    assert "misaddressed: IDENTITY says joint 4 (j4) answers at 0x13, where the configuration has j3" in \
        entries[0x13]["problems"][0]
    assert "misaddressed: j3 (by IDENTITY) answers here" in entries[0x40]["problems"][0]
    from pathlib import Path
    from bioscara.config import read_config
    text = Path(read_config().source).read_text()
    three = tmp_path / "three.toml"
    three.write_text(text[:text.index("[joints.j4]")] + text[text.index("[gripper]"):].replace("j4 = 2.95\n", ""))
    code, out, _ = run(capsys, "scan", "--json", "--config", str(three), bus=_bus_with(config))
    entries = {e["address"]: e for e in json.loads(out)}
    assert code == 1 and entries[0x14]["problems"] == ["unexpected: not in the configuration"]
    code, out, _ = run(capsys, "scan")
    assert code == 0 and "problems" in out


def test_a_bus_error_names_the_joint_and_the_address(capsys: pytest.CaptureFixture[str], config) -> None:  # type: ignore[no-untyped-def]
    code, _, err = run(capsys, "info", "j4", bus=_bus_with(config, J4=None))
    assert code == 1 and err.startswith("error: j4: I2C 0x14 (sim:virtual): EREMOTEIO no ACK")


def test_one_shape_for_the_command_line(capsys: pytest.CaptureFixture[str], tmp_path) -> None:  # type: ignore[no-untyped-def]
    from bioscara import __version__
    code, out, _ = run(capsys, "--version")
    assert code == 0 and out.strip() == f"bioscara {__version__}"
    assert json.loads(run(capsys, "--json", "stop")[1]) == json.loads(run(capsys, "stop", "--json")[1])
    code, _, err = run(capsys, "--json", "shell")
    assert code == 2 and "`bioscara shell` takes no --json" in err
    for argv, option in ((("plot", "x.csv", "--config", "a.toml"), "--config"), (("demo", "--bus", "smbus:1"), "--bus"),
                         (("console", "/dev/ttyACM0", "--json"), "--json"), (("sim", "stop", "--bus", "smbus:1"), "--bus"),
                         (("scan", "--protocol", "v2"), "--protocol"),
                         (("flash", "--dry-run", "--joint", "j1", "--protocol", "v2"), "--protocol")):
        code, _, err = run(capsys, *argv)
        assert code == 2 and f"unrecognized arguments: {option}" in err and len(err.splitlines()) == 1, argv
    code, _, err = run(capsys, "home", "j1", "--timeout", "-5")
    assert code == 2 and "'-5' must be > 0 s" in err


def test_piped_output_is_plain_lines(capsys: pytest.CaptureFixture[str], bus: SimBus) -> None:
    code, out, err = run(capsys, "home", "j3", bus=bus)
    assert code == 0
    assert re.fullmatch(r"j3: homed at \+2\.\d{5} rad\nj3: travelled [-+]\d\.\d{3} rad\nhomed j3 in \d+\.\d s\n", out), out
    assert re.match(r"j3 homing, travel [-+]\d\.\d{3} rad; \d+\.\d s$", err.splitlines()[0]), "progress on stderr"
    assert "\x1b" not in out
    code, out, _ = run(capsys, "monitor", "--samples", "2", bus=bus)
    lines = out.splitlines()
    assert len(lines) == 3 and all(line.count(" rad/s") == 3 and " m/s" in line for line in lines[:2])


def test_hardware_doc_has_the_generated_pin_map_and_the_readme_cites_only_files_in_the_repo() -> None:
    from pathlib import Path

    from bioscara import firmware_flash, wiring
    root = Path(__file__).resolve().parent.parent
    assert wiring.markdown(firmware_flash.joint_config("J1")[1]) in (root / "docs" / "hardware.md").read_text(), \
        "docs/hardware.md: paste the output of `bioscara pins j1 --markdown`"
    readme = (root / "README.md").read_text()
    for cited in re.findall(r"`([\w./-]+\.md)`", readme):
        assert (root / cited).exists(), cited


def test_the_hardware_doc_covers_the_way_to_a_real_arm() -> None:
    """docs/hardware.md has what a first real arm needs, with the commands that exist."""
    from pathlib import Path

    from bioscara.cli import build_parser
    doc = (Path(__file__).resolve().parent.parent / "docs" / "hardware.md").read_text()
    for section in ("## Parts", "## Wiring of one joint board", "## MicroPython on the Pico",
                    "## The joint firmware: `bioscara flash`", "## The joint bus on a Raspberry Pi",
                    "## Power-up order", "## First power-up checklist"):
        assert section in doc, section
    for fact in ("MicroPython 1.26 or newer", "dtparam=i2c_arm=on", "i2c_arm_baudrate", "Pull-ups",
                 "Clock stretching", "BIOSCARA_BUS"):
        assert fact in doc, fact
    commands = set(build_parser()._subparsers._group_actions[0].choices)  # type: ignore[union-attr]
    used = set(re.findall(r"`bioscara (\w+)", doc)) | set(re.findall(r"^bioscara (\w+)", doc, re.M))
    assert used and used <= commands, used - commands
    for step in ("scan", "flash", "home", "move"):
        assert step in used, step


def test_user_config_file_and_bus_environment_variable(capsys: pytest.CaptureFixture[str], tmp_path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    import os
    from pathlib import Path

    from bioscara.config import read_config, user_config_path
    path = user_config_path()
    assert path == Path(os.environ["XDG_CONFIG_HOME"]) / "bioscara" / "arm.toml"
    path.parent.mkdir(parents=True)
    path.write_text(Path(read_config().source).read_text().replace("address = 0x14", "address = 0x24"))
    code, out, _ = run(capsys, "info", "j4", "--json")
    assert code == 0 and json.loads(out)["address"] == 0x24, "the user's configuration was used"
    from bioscara.config import load_config
    from bioscara.hardware import open_arm
    assert load_config().joints["j4"].address == 0x24, "and the API's, as the README's script calls it"
    monkeypatch.setenv("BIOSCARA_BUS", "smbus:/dev/i2c-77")
    code, _, err = run(capsys, "scan")
    assert code == 1 and "cannot open /dev/i2c-77" in err, "the variable chose the bus"
    assert load_config().bus_url == "smbus:/dev/i2c-77"
    with pytest.raises(OSError, match="cannot open /dev/i2c-77"):
        open_arm()
    monkeypatch.setenv("BIOSCARA_BUS", "pigeon:")
    code, _, err = run(capsys, "scan")
    assert code == 2 and "in $BIOSCARA_BUS" in err


def test_the_unit_hint_only_when_the_value_makes_sense_in_degrees_or_mm(capsys: pytest.CaptureFixture[str],
                                                                       bus: SimBus) -> None:
    """2.7 is j3's limit overshot in rad (±2.627), not 2.7 degrees: no hint; 90 is degrees."""
    code, _, err = run(capsys, "move", "j3", "2.7", bus=bus)
    assert code == 2 and "2.7 rad is outside the limits" in err and "degrees" not in err
    code, _, err = run(capsys, "move", "j3", "90", bus=bus)
    assert code == 2 and "90 degrees is 1.57080 rad" in err


@pytest.mark.parametrize("argv", [["--bus", "sim:virtual", "scan", "--json"], ["scan", "--bus", "sim:virtual", "--json"],
                                  ["--json", "--protocol", "legacy", "info", "j1"], ["--config", "{config}", "--json", "scan"]])
def test_global_options_before_or_after_the_command(capsys: pytest.CaptureFixture[str], argv: list[str]) -> None:
    from bioscara.config import load_config
    argv = [arg.replace("{config}", load_config().source) for arg in argv]
    code, out, err = run(capsys, *argv)
    assert code == 0, err
    if "info" in argv:
        assert json.loads(out)["protocol"] == "legacy"
    else:
        assert [d["joint"] for d in json.loads(out)] == ["j1", "j2", "j3", "j4"]


def test_a_global_option_the_command_does_not_take_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, "--bus", "sim:virtual", "pins", "j1")
    assert code == 2 and "`bioscara pins` takes no --bus" in err


def test_piped_tables_are_plain_columns(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "scan")  # capsys: stdout is not a terminal
    assert code == 0 and re.search(r"^ *0x11 +j1 +joint", out, re.M)
    assert not set(out) & set("┏┃━│┌└─"), out


def test_pins_of_a_joint_that_does_not_exist_names_the_joints(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, "pins", "j7")
    assert code == 2 and err.strip() == "error: no joint j7; the joints are j1, j2, j3, j4 (or a FILE.json you wrote)"


def test_a_json_lines_recording_cut_by_a_kill_still_plots(capsys: pytest.CaptureFixture[str], tmp_path,
                                                          caplog: pytest.LogCaptureFixture) -> None:
    record = tmp_path / "trace.jsonl"
    run(capsys, "monitor", "--samples", "5", "--record", str(record))
    text = record.read_text()
    record.write_text(text[:len(text) - 20])  # the last row half written, as a kill leaves it
    code, out, err = run(capsys, "plot", str(record), "--json")
    assert code == 0, err
    assert "skipped the last line, cut short" in caplog.text and json.loads(out)["rows"] == 4
