"""The emulator's own tests (node --test, one pytest test per file): the datasheet fixes on the
register level and through MicroPython, boot, boards stepped together."""

import subprocess

import pytest

from chip.paths import CHIP_DIR
from chip.testing import requires_chip

pytestmark = requires_chip

NODE_TESTS = sorted(p.name for p in (CHIP_DIR / "test").glob("*.test.mjs"))


@pytest.mark.parametrize("name", NODE_TESTS)
def test_node_test_file_passes(name: str) -> None:
    result = subprocess.run(["node", "--test", f"test/{name}"], cwd=CHIP_DIR, capture_output=True, text=True,
                            timeout=280)
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]
