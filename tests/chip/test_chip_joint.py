"""The joint firmware on the emulated Pico, deployed as a user deploys it.

With no TMC2209 on the board's UART (a bare Pico), the joint must boot from /main.py, say on the
console why it disabled itself, and keep serving its console: a clear message and a safe joint.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import serial

from bioscara.firmware.startup import BOOT_ONLY
from chip import fsimage
from chip.board import EmulatedPico
from chip.testing import requires_chip

pytestmark = requires_chip

TMC_MISSING = b"J1 ERROR motor fault, joint disabled until reset: TMCError('TMC2209 UART: no clean echo"


def _status(console: serial.Serial) -> bytes:
    """The joint's `status` debug command, answered by main.py's control loop (not the REPL)."""
    console.write(b"status\r\n")
    return console.read_until(b"stall ")


def test_bioscara_flash_deploys_verifies_and_boots_the_joint() -> None:
    with EmulatedPico() as pico:
        result = subprocess.run([sys.executable, "-m", "bioscara.cli", "flash", pico.port(), "--joint", "J1", "--json"],
                                capture_output=True, text=True, timeout=240)
        assert result.returncode == 0, result.stdout + result.stderr
        report = json.loads(result.stdout)
        assert report["verified"] and report["compiled"]
        assert sorted(report["added"]) == sorted(fsimage.joint_files("J1"))
        # The files on the board's flash are the deployed image, byte for byte.
        on_flash = fsimage.read_image(pico.fs_image())
        assert {p: on_flash[p] for p in report["added"]} == fsimage.joint_files("J1")
        console = serial.Serial(pico.port(), timeout=60)
        try:
            status = _status(console)
        finally:
            console.close()
        assert b"J1 at 0x11" in status and b"disabled yes" in status, status


def test_the_deployed_image_boots_the_joint_with_a_clear_message_and_a_safe_joint(joint_image: Path) -> None:
    with EmulatedPico(joint_image) as pico:
        console = serial.Serial(pico.port(), timeout=60)
        try:
            assert console.read_until(TMC_MISSING).endswith(TMC_MISSING)
            status = _status(console)
            assert b"flags NOTHOMED|NOTENABLED" in status and b"disabled yes" in status, status
            console.write(b"\x03")  # Ctrl-C: the loop leaves the joint safe, then the REPL
            assert console.read_until(b">>> ").find(b"stopped by Ctrl-C: motor off, joint off the bus") >= 0
            # The boot task (PicoStepper.begin) ran: what only boot needs is off the heap again.
            names = tuple("joint." + m for m in BOOT_ONLY)  # asked by name: importing startup would load it
            console.write(b"import sys; print([m for m in %r if m in sys.modules])\r\n" % (names,))
            assert console.read_until(b"]\r\n").endswith(b"\r\n[]\r\n")
        finally:
            console.close()
