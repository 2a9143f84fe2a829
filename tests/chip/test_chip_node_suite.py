"""The emulator's own tests (node --test): the datasheet fixes on the register level, and boot."""

import subprocess

from chip.paths import CHIP_DIR
from chip.testing import requires_chip

pytestmark = requires_chip


def test_node_suite_passes() -> None:
    files = sorted(str(p.relative_to(CHIP_DIR)) for p in (CHIP_DIR / "test").glob("*.test.mjs"))
    result = subprocess.run(["node", "--test", *files], cwd=CHIP_DIR, capture_output=True, text=True, timeout=240)
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]
