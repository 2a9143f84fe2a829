"""The host's `Bus` over the emulated S32 (tests/s32_emu.py): the host's own `Joint`, legacy and
v2 links talk to the S32 image booted under Qiling as they talk to a real joint.

Qiling lives in an environment of its own (build/qiling-venv, `make s32-emu`), so the emulator is a
subprocess and `EmulatedS32Bus` its client: one JSON line a request on its stdin, one a reply on
its stdout (`s32_emu.Server`).

Virtual time: the bus clock (`monotonic`) is the emulated S32's, which stands still between
requests. A transaction advances it by its wire time at `speed_hz` (each event, address byte, data
byte or NACK, takes 9 clocks), plus whatever the joint holds SCL stretched while its interrupt
serves an event; `sleep` runs the emulated S32 for that long. The host's waits (`Joint.home`'s
polls, `V2Link`'s retries, a test's silence for the deadman) therefore happen in the joint's time,
deterministically, however slow the emulator is (6 to 18 s of wall time per emulated second on
this project's shared two-core machine, by its load).
"""

from __future__ import annotations

import errno
import json
import pathlib
import subprocess
import tempfile
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Iterator

from bioscara import s32flash
from bioscara.bus.base import Bus

ROOT = pathlib.Path(__file__).resolve().parents[1]
IMAGE = ROOT / "build" / "s32" / "firmware.bin"
EMULATOR_PYTHON = ROOT / "build" / "qiling-venv" / "bin" / "python"
EMULATOR = ROOT / "tests" / "s32_emu.py"
USTEPS_PER_MOTOR_DEGREE = 51200 / 360  # 200 full steps of 256 microsteps a turn (ustepper-model.md 2)


def missing() -> str | None:
    """What the emulated S32 lacks here, in words, or None."""
    if not IMAGE.exists():
        return ("build/s32/firmware.bin is missing: make s32-image builds it (it needs "
                "../shared/stm32/micropython-v1.28.0-stm32-src.tar.xz and arm-none-eabi-gcc)")
    if not EMULATOR_PYTHON.exists():
        return "build/qiling-venv is missing: make s32-emu installs Qiling 1.4.6 with unicorn 2.0.1.post1"
    return None


class EmulatorError(Exception):
    """The emulator failed (the emulated CPU faulted, or the process ended): with its log."""


@dataclass(frozen=True)
class InstructionCount:
    """Instructions the emulated CPU executed over a stretch of requests (`EmulatedS32Bus.counting`):
    all, those in I2C1's interrupts, and the main loop's iterations meanwhile. One instruction is
    taken as one cycle: an estimate."""

    total: int = 0
    in_i2c: int = 0
    iterations: int = 0

    @property
    def per_iteration(self) -> int:
        """Instructions per main-loop iteration, interrupts included."""
        return self.total // max(self.iterations, 1)


class EmulatedS32Bus(Bus):
    """The joint bus (I2C1) of one emulated S32 booted from `flash` (image + configuration, as
    `bioscara flash --board s32` writes it): `flash_for(joint, directory)` composes one."""

    scheme = "s32emu"

    def __init__(self, flash: pathlib.Path, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.log = ""  # the S32's UART output so far (its log lines)
        self.now_us = 0
        self.boot_wall_s = 0.0
        self._stderr = tempfile.TemporaryFile()
        self._process = subprocess.Popen([str(EMULATOR_PYTHON), str(EMULATOR), str(flash)], stdin=subprocess.PIPE,
                                         stdout=subprocess.PIPE, stderr=self._stderr, text=True, bufsize=1)
        if not self._receive()["booted"]:
            self.close()
            raise EmulatorError(f"the emulated S32 did not boot:\n{self.log}")

    @staticmethod
    def flash_for(joint: str, directory: pathlib.Path) -> pathlib.Path:
        """The composed flash of `joint` (J1..J4) with the built image, beside a link to its ELF
        (the main-loop estimate reads its symbols)."""
        flash = directory / f"flash_{joint.lower()}.bin"
        flash.write_bytes(s32flash.build(joint, IMAGE).composed())
        elf = directory / "firmware.elf"
        if not elf.exists():
            elf.symlink_to(IMAGE.with_name("firmware.elf"))
        return flash

    def describe(self) -> str:
        return "s32emu:virtual"

    def arm_lock_path(self) -> None:
        return None  # the emulated joint lives in this process's child: no other program reaches it

    def request(self, op: str, **fields: Any) -> dict[str, Any]:
        """One request to the emulator; its reply."""
        if self._process.poll() is not None:
            raise EmulatorError(f"the emulator has ended:\n{self._stderr_text()}")
        self._process.stdin.write(json.dumps({"op": op, **fields}) + "\n")
        self._process.stdin.flush()
        return self._receive()

    def _receive(self) -> dict[str, Any]:
        line = self._process.stdout.readline()
        if not line:
            raise EmulatorError(f"the emulator ended without a reply:\n{self.log}\n{self._stderr_text()}")
        reply = json.loads(line)
        self.log += reply["log"]
        self.now_us = reply["us"]
        if "fault" in reply:
            raise EmulatorError(f"the emulated CPU stopped: {reply['fault']}\n{self.log}")
        return reply

    def _stderr_text(self) -> str:
        self._stderr.seek(0)
        return self._stderr.read().decode(errors="replace")[-4000:]

    def _transfer_once(self, addr: int, write: bytes | None, read_len: int) -> bytes:
        reply = self.request("transfer", address=addr, write=None if write is None else write.hex(),
                             read=read_len, speed_hz=self.speed_hz)
        if "nack" in reply:
            raise OSError(errno.EREMOTEIO, reply["nack"])
        if "timeout" in reply:
            raise TimeoutError(reply["timeout"])
        return bytes.fromhex(reply["data"])

    def _probe(self, addr: int) -> bool:
        try:
            self._transfer_once(addr, b"", 0)
        except OSError:
            return False
        return True

    def sleep(self, seconds: float) -> None:
        """Run the emulated S32 for `seconds` of its time."""
        with self._lock:
            self.request("run", us=round(seconds * 1e6))

    def monotonic(self) -> float:
        return self.now_us / 1e6

    def board(self) -> dict[str, Any]:
        """The chips' side: the TMC5130's registers by name (register units), VACTUAL, the rotor's
        position and wall (usteps)."""
        return self.request("board")

    def set_wall(self, position: int | None, side: int = 1) -> None:
        """A wall the rotor stops at, `position` usteps, stopping travel upward (`side` 1) or
        downward (-1); None removes it."""
        self.request("wall", position=position, side=side)

    @contextmanager
    def counting(self) -> Iterator[list[InstructionCount]]:
        """Count instructions over the block's requests: the yielded list holds the count after."""
        result: list[InstructionCount] = []
        self.request("count", on=True)
        try:
            yield result
        finally:
            reply = self.request("count", on=False)
            result.append(InstructionCount(reply["total"], reply["in_i2c"], reply["iterations"]))

    def close(self) -> None:
        if not self._closed and self._process.poll() is None:
            self._process.stdin.close()
            try:
                self._process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self._process.kill()
                self._process.wait()
            self._process.stdout.close()
        self._stderr.close()
        super().close()
