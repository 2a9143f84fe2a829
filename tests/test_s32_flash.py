"""`bioscara flash --board s32`: the dfu-util runs it makes, what lands in flash, and its errors.

No S32 here: the outermost edge is faked, a `dfu-util` executable on PATH that keeps the board's
256 KB of flash in a file (DfuSe download at -s ADDRESS, upload of -s ADDRESS:LENGTH, `leave`)
and logs its command lines. Everything between the CLI and that process is the real code.
"""

from __future__ import annotations

import json
import os
import stat
import sys
from pathlib import Path

import pytest

from bioscara import cli, s32flash
from bioscara.firmware.config import schema as firmware_config

FAKE_DFU = r'''#!PYTHON
"""A uStepper S32 in its ROM DFU bootloader, as dfu-util shows it (flash in $FAKE_DFU_DIR/flash.bin)."""
import os, sys
state = os.environ["FAKE_DFU_DIR"]
with open(os.path.join(state, "argv.log"), "a") as log:
    log.write(" ".join(sys.argv[1:]) + "\n")
mode = os.environ.get("FAKE_DFU_MODE", "")
if mode == "absent":
    print("dfu-util 0.11\ndfu-util: No DFU capable USB device available", file=sys.stderr)
    sys.exit(74)
args = sys.argv[1:]
spec = args[args.index("-s") + 1].split(":")
address = int(spec[0], 16) - 0x08000000
flash_path = os.path.join(state, "flash.bin")
if not os.path.exists(flash_path):
    open(flash_path, "wb").write(b"\xff" * 262144)
flash = bytearray(open(flash_path, "rb").read())
if "-D" in args:
    data = open(args[args.index("-D") + 1], "rb").read()
    if address + len(data) > len(flash):
        print("dfu-util: Last page at 0x%08x is not writeable" % (0x08000000 + len(flash)), file=sys.stderr)
        sys.exit(74)
    if mode == "corrupt":
        data = data[:-2] + b"\x00\xff"
    flash[address:address + len(data)] = data
    open(flash_path, "wb").write(flash)
elif "-U" in args:
    length = int([s for s in spec[1:] if s.isdigit()][0])
    open(args[args.index("-U") + 1], "wb").write(bytes(flash[address:address + length]))
if "leave" in spec:
    open(os.path.join(state, "left"), "w").write("1")
'''


@pytest.fixture
def dfu(tmp_path, monkeypatch):
    """The fake dfu-util first on PATH; returns its state folder."""
    bin_dir, state = tmp_path / "bin", tmp_path / "s32"
    bin_dir.mkdir()
    state.mkdir()
    tool = bin_dir / "dfu-util"
    tool.write_text(FAKE_DFU.replace("PYTHON", sys.executable))
    tool.chmod(tool.stat().st_mode | stat.S_IEXEC)
    monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv("FAKE_DFU_DIR", str(state))
    return state


@pytest.fixture
def image(tmp_path):
    path = tmp_path / "firmware.bin"
    path.write_bytes(bytes(range(256)) * 800)  # 204,800 bytes, like an image
    return path


def run(capsys, *args: str) -> tuple[int, str, str]:
    code = cli.main(["flash", "--board", "s32", *args])
    out, err = capsys.readouterr()
    return code, out, err


def test_flashing_writes_image_and_configuration_and_reads_it_back(capsys, dfu, image):
    code, out, err = run(capsys, "--joint", "j2", "--image", str(image), "--json")
    assert code == 0, err
    flash = (dfu / "flash.bin").read_bytes()
    assert flash[:image.stat().st_size] == image.read_bytes()
    assert set(flash[image.stat().st_size:s32flash.IMAGE_LIMIT]) == {0xFF}, "erased between image and config"
    stored = flash[s32flash.IMAGE_LIMIT:].split(b"\xff")[0]
    cfg = firmware_config.parse(json.loads(stored), "flash")
    assert cfg.valid and cfg.joint == "J2" and cfg.address == 0x12
    assert cfg.motor == {"backend": "s32"} and cfg.i2c.bus == 1
    calls = (dfu / "argv.log").read_text().splitlines()
    assert len(calls) == 2
    assert calls[0].startswith("-a 0 -s 0x08000000 -D ")
    assert calls[1].startswith(f"-a 0 -s 0x0803f000:{len(stored) + 1}:leave -U ")
    assert (dfu / "left").exists(), "the firmware was started"
    report = json.loads(out)
    assert report["joint"] == "j2" and report["address"] == 0x12 and report["verified"]
    assert report["config_address"] == "0x0803f000"


def test_no_board_in_dfu_mode_says_how_to_get_there(capsys, dfu, image, monkeypatch):
    monkeypatch.setenv("FAKE_DFU_MODE", "absent")
    code, out, err = run(capsys, "--joint", "j1", "--image", str(image))
    assert code != 0 and "BOOT0" in err and "Traceback" not in err


def test_a_configuration_that_does_not_read_back_fails(capsys, dfu, image, monkeypatch):
    monkeypatch.setenv("FAKE_DFU_MODE", "corrupt")
    code, out, err = run(capsys, "--joint", "j1", "--image", str(image))
    assert code != 0 and "verification failed" in err


def test_a_missing_or_oversized_image_is_refused_before_dfu_util_runs(capsys, dfu, tmp_path):
    code, _, err = run(capsys, "--joint", "j1", "--image", str(tmp_path / "none.bin"))
    assert code != 0 and "make s32-image" in err
    big = tmp_path / "big.bin"
    big.write_bytes(b"\0" * (s32flash.IMAGE_LIMIT + 1))
    code, _, err = run(capsys, "--joint", "j1", "--image", str(big))
    assert code != 0 and "must fit" in err
    assert not (dfu / "argv.log").exists(), "no device was touched"


def test_without_dfu_util_the_error_names_the_package(capsys, image, monkeypatch, tmp_path):
    monkeypatch.setenv("PATH", str(tmp_path))
    code, _, err = run(capsys, "--joint", "j1", "--image", str(image))
    assert code != 0 and "apt-get install dfu-util" in err


def test_a_pico_configuration_is_refused_for_an_s32(capsys, dfu, image, tmp_path):
    user = tmp_path / "j3.json"
    user.write_text(json.dumps({"joint": "J3", "address": 19, "motor": {"backend": "pico"}}))
    code, _, err = run(capsys, "--joint-config", str(user), "--image", str(image))
    assert code != 0 and 'must be "s32"' in err
    user.write_text(json.dumps({"joint": "J3", "address": 19, "i2c": {"bus": 1}, "motor": {"backend": "s32"}}))
    code, out, err = run(capsys, "--joint-config", str(user), "--image", str(image), "--json")
    assert code == 0, err
    assert json.loads(out)["config"]["address"] == 19


def test_a_dry_run_writes_nothing(capsys, dfu, image):
    code, out, err = run(capsys, "--joint", "j4", "--image", str(image), "--dry-run")
    assert code == 0, err
    assert "dry run" in out and not (dfu / "argv.log").exists()


def test_a_port_is_refused(capsys, dfu, image):
    code, _, err = run(capsys, "/dev/ttyACM0", "--joint", "j1", "--image", str(image))
    assert code != 0 and "give no PORT" in err
