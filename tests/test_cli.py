"""The `bioscara` command against the simulator: what users type, what they get back."""

from __future__ import annotations

from bioscara.firmware import protocol as P

import csv
import json

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
    assert code == 1 and not j3["spec_matches"] and "different protocol specs" in j3["problem"]


def test_home_all_then_move_reaches_the_target(capsys: pytest.CaptureFixture[str], bus: SimBus) -> None:
    code, out, _ = run(capsys, "home", "all", "--json", bus=bus)
    assert code == 0 and all(j["homed"] for j in json.loads(out.splitlines()[-1])["joints"].values())
    code, out, _ = run(capsys, "move", "j3", "1.25", "--json", bus=bus)
    assert code == 0 and abs(json.loads(out)["position"] - 1.25) <= 1e-3
    assert abs(bus.joint_position(0x13) - 1.25) < 0.005, "the simulated joint is really there"


def test_move_enforces_limits_and_homing(capsys: pytest.CaptureFixture[str], bus: SimBus) -> None:
    code, _, err = run(capsys, "move", "j1", "4.0", bus=bus)
    assert code == 1 and "outside the limits [-3.04647, 3.04647]" in err and len(err.strip().splitlines()) == 1
    code, _, err = run(capsys, "move", "j1", "1.0", bus=bus)
    assert code == 1 and "run `bioscara home j1` first" in err


def test_monitor_records_rows_with_the_expected_columns_and_plot_renders(
        capsys: pytest.CaptureFixture[str], tmp_path) -> None:
    record = tmp_path / "trace.csv"
    code, out, _ = run(capsys, "monitor", "--samples", "25", "--rate", "50", "--record", str(record), "--json")
    assert code == 0 and json.loads(out)["rows"] == 25
    with open(record) as f:
        meta = json.loads(f.readline()[2:])
        rows = list(csv.DictReader(f))
    assert meta["spec_hash"] and meta["rate_hz"] == 50.0
    assert len(rows) == 25 and list(rows[0]) == ["time", "cycle"] + [
        f"j{i}/{v}" for i in range(1, 5) for v in ("position", "velocity", "flags", "home")] + ["fault"]
    assert float(rows[-1]["time"]) - float(rows[0]["time"]) == pytest.approx(24 / 50, abs=1e-3)
    code, out, _ = run(capsys, "plot", str(record), "--json")
    png = json.loads(out)["png"]
    with open(png, "rb") as f:
        assert f.read(8) == b"\x89PNG\r\n\x1a\n"


def test_monitor_records_json_lines(capsys: pytest.CaptureFixture[str], tmp_path) -> None:
    record = tmp_path / "trace.jsonl"
    run(capsys, "monitor", "--samples", "3", "--record", str(record))
    lines = [json.loads(line) for line in record.read_text().splitlines()]
    assert "spec_hash" in lines[0]["meta"] and len(lines) == 4
    assert set(lines[1]["values"]) >= {"j1/position", "j4/flags"}


def test_enable_disable_and_stop(capsys: pytest.CaptureFixture[str], bus: SimBus) -> None:
    code, out, _ = run(capsys, "enable", "j1", "j2", "--json", bus=bus)
    assert code == 0 and [d["joint"] for d in json.loads(out)] == ["j1", "j2"]
    assert bus.joint(0x11).core.stallguard, "stall detection on with the configured threshold"
    code, out, _ = run(capsys, "stop", "--json", bus=bus)
    assert code == 0 and set(json.loads(out).values()) == {"stopped"}
    code, out, _ = run(capsys, "disable", bus=bus)
    assert code == 0 and all(bus.joint(a).core.flags & 0x08 for a in (0x11, 0x12, 0x13, 0x14))


def test_info_reports_identity_and_flags(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "info", "j4", "--json")
    info = json.loads(out)
    assert code == 0 and info["joint_id"] == 4 and info["flags"] == "NOTHOMED|NOTENABLED" and info["position"] is None


def test_scan_and_info_show_the_protocol_and_protocol_forces_one(capsys: pytest.CaptureFixture[str],
                                                                 bus: SimBus) -> None:
    code, out, _ = run(capsys, "scan", "--json", bus=bus)
    assert code == 0 and all(d["protocols"] == "legacy+v2" for d in json.loads(out))
    code, out, _ = run(capsys, "info", "j2", "--json", bus=bus)
    info = json.loads(out)
    assert code == 0 and info["protocol"] == "v2" and info["v2_link"]["bad_states"] == 0
    assert bus.joint(0x12).protocol == 1, "info returns the joint to the legacy map when done"
    code, out, _ = run(capsys, "info", "j2", "--json", "--protocol", "legacy", bus=bus)
    assert code == 0 and json.loads(out)["protocol"] == "legacy" and "v2_link" not in json.loads(out)
    with pytest.raises(SystemExit) as stop:
        run(capsys, "info", "j2", "--protocol", "v3", bus=bus)
    assert stop.value.code == 2 and "invalid choice: 'v3'" in capsys.readouterr().err


def test_errors_are_one_line_and_non_zero(capsys: pytest.CaptureFixture[str], tmp_path) -> None:
    bad = tmp_path / "arm.toml"
    bad.write_text("[bus]\nattempts = 99\n")
    code, out, err = run(capsys, "scan", "--config", str(bad))
    assert code == 2 and "bus.attempts = 99 is out of range 1..10" in err and "Traceback" not in err + out
    code, _, err = run(capsys, "info", "j7")
    assert code == 1 and err.strip().count("\n") == 0 and "no joint 'j7'" in err
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
        assert code == 1 and "cycle rate must be in (0, 10000] Hz" in err and "Traceback" not in err + out
    assert all(bus.joint(a).core.flags & 0x08 for a in (0x11, 0x12, 0x13, 0x14)), "nothing was enabled"


def test_disable_carries_on_past_a_missing_joint(capsys: pytest.CaptureFixture[str], bus: SimBus) -> None:
    run(capsys, "enable", bus=bus)
    bus.joint(0x11).connected = False
    code, out, _ = run(capsys, "disable", "--json", bus=bus)
    results = {d["joint"]: d["result"] for d in json.loads(out)}
    assert code == 1 and results["j1"].startswith("FAILED") and results["j4"].startswith("disabled")
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
    summary = json.loads(out)
    assert code == 1 and summary["samples"] == 5 and summary["errors"] == 5


def test_plot_refuses_what_is_not_a_recording(capsys: pytest.CaptureFixture[str], tmp_path) -> None:
    for name, text in (("a.jsonl", '{"meta": {"bus": "sim:"}}\n'), ("b.jsonl", '{"meta": {"joints": ["j1"], '
                       '"bus": "sim:", "spec_hash": "0", "rate_hz": 1}}\n[1, 2]\n'), ("c.csv", "time,cycle\n1,2\n")):
        path = tmp_path / name
        path.write_text(text)
        code, out, err = run(capsys, "plot", str(path))
        assert code == 1 and "not a bioscara recording" in err and "Traceback" not in err + out
