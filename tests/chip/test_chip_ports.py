"""`bioscara ports` on the emulated Pico, a real MicroPython on a serial port: a stock board is told
as a MicroPython board to flash and stays usable; a board running the joint firmware is told as
that joint's debug port and keeps running."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path


from bioscara.commands.ports import probe
from chip.board import EmulatedPico
from chip.testing import joint_image, read_console_until, requires_chip  # noqa: F401 (a fixture)

pytestmark = requires_chip


def test_a_stock_board_is_a_micropython_board_and_stays_usable() -> None:
    with EmulatedPico() as pico:
        found = probe(pico.port())
        assert found["kind"] == "MicroPython board", found
        assert found["use"] == f"bioscara flash {pico.port()} --joint j1"
        mpremote = [sys.executable, "-m", "mpremote", "connect", pico.port(), "exec", "print(6 * 7)"]
        result = subprocess.run(mpremote, capture_output=True, text=True, timeout=60)
        assert result.stdout.strip() == "42", result.stderr


def test_a_running_joint_is_its_debug_port_and_keeps_running(joint_image: Path) -> None:  # noqa: F811
    with EmulatedPico(joint_image) as pico:
        # No motor on this board: the joint boots into its motor fault, then serves its port.
        seen = read_console_until(pico.port(), b"booted: ", 120)
        assert b"booted: " in seen, seen
        found = probe(pico.port())
        assert found["kind"] == "joint debug port", found
        assert found["detail"] == "j1 at 0x11"
        assert probe(pico.port())["kind"] == "joint debug port", "the probe left the firmware running"
