"""The S32 image booted on the emulated board (tests/s32_emu.py: Qiling's STM32F401 with the
TMC5130 and TLE5012B models on SPI2/SPI3, in virtual time): it boots as J1 with the heap the issue
asks to keep free, joins the bus and answers the host's legacy reads on I2C1 (the STM32F4 I2C target
model), and its main loop drives the TMC5130 with no motor fault."""

from __future__ import annotations

import pathlib
import re
import subprocess

import pytest

from bioscara import s32flash
from bioscara.firmware.spec import protocol as P

ROOT = pathlib.Path(__file__).resolve().parents[1]
IMAGE = ROOT / "build" / "s32" / "firmware.bin"
EMULATOR_PYTHON = ROOT / "build" / "qiling-venv" / "bin" / "python"
HEAP_FREE_TARGET = 12 * 1024


@pytest.fixture(scope="module")
def boot(tmp_path_factory) -> subprocess.CompletedProcess:
    if not IMAGE.exists():
        pytest.skip("build/s32/firmware.bin is missing: make s32-image builds it (it needs "
                    "../shared/stm32/micropython-v1.28.0-stm32-src.tar.xz and arm-none-eabi-gcc)")
    if not EMULATOR_PYTHON.exists():
        pytest.skip("build/qiling-venv is missing: make s32-emu installs Qiling 1.4.6 with unicorn 2.0.1.post1")
    flash = tmp_path_factory.mktemp("s32") / "flash_j1.bin"
    flash.write_bytes(s32flash.build("J1", IMAGE).composed())
    return subprocess.run([str(EMULATOR_PYTHON), str(ROOT / "tests" / "s32_emu.py"), str(flash)],
                          capture_output=True, text=True, timeout=600, check=False)


def test_the_emulated_s32_boots_as_j1_and_joins_the_bus(boot):
    assert boot.returncode == 0, boot.stderr
    assert "J1 INFO J1 ready at 0x11" in boot.stderr
    booted = re.search(r"J1 INFO booted: (\d+) bytes of heap free", boot.stderr)
    assert booted is not None, boot.stderr
    assert int(booted.group(1)) >= HEAP_FREE_TARGET


def test_the_main_loop_drives_the_tmc5130_without_a_motor_fault(boot):
    assert boot.returncode == 0, boot.stderr
    assert "motor fault" not in boot.stderr and " ERROR " not in boot.stderr, boot.stderr
    datagrams = re.search(r"then (\d+) TMC5130 datagrams in \d+ ms", boot.stderr)
    assert datagrams is not None and int(datagrams.group(1)) > 0, boot.stderr


def _legacy_read(boot, name: str) -> tuple[tuple, int]:
    """The emulated joint's reply to the host's read of register `name`, decoded as the host
    decodes it (bioscara.link.legacy): (values, flags)."""
    assert boot.returncode == 0, boot.stderr
    read = re.search(rf"legacy {name} read on I2C1 at 0x11: ([0-9a-f]*)", boot.stderr)
    assert read is not None, boot.stderr
    reply = bytes.fromhex(read.group(1))
    return P.register(getattr(P, name)).decode(reply[:-1]), reply[-1]


def test_the_joint_answers_the_host_s_identity_read_on_the_joint_bus(boot):
    (protocol, major, minor, patch, joint_id, spec_hash), flags = _legacy_read(boot, "IDENTITY")
    assert not flags & P.FLAG_ERROR
    assert (protocol, joint_id, spec_hash) == (P.PROTOCOL_VERSION, 1, P.SPEC_HASH)


def test_the_joint_reports_no_angle_moved_at_rest(boot):
    (degrees,), flags = _legacy_read(boot, "ANGLEMOVED")
    assert not flags & P.FLAG_ERROR
    assert degrees == 0.0
