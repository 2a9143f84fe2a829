"""An emulated uStepper S32: the built image (make s32-image) on Qiling's STM32F401 with the
chips the board carries, modelled at the register level (firmware/tests/s32_fakes.py):

    SPI2  a TMC5130 (40-bit datagrams, 5 bytes with the firmware's chip select low)
    SPI3  a TLE5012B (command word out, data and safety word in: 6 bytes a transfer)

and the joint's configuration in the last 4 KB of flash: the flash file is composed as
`bioscara flash --board s32` writes it (bioscara.s32flash.S32Image.composed). USART2 carries the
REPL and the firmware's log. No timing fidelity: figures from here are functional (what the
firmware prints, its heap), never times.

Needs Qiling 1.4.6 with unicorn 2.0.1.post1 (unicorn 2.1 breaks its memory map), which do not
share an environment with the project's: `make s32-emu` makes build/qiling-venv, and

    build/qiling-venv/bin/python tests/s32_emu.py FLASH.bin

boots FLASH.bin and prints `s32.heap_free_after_boot_kb` (bench/s32_image.py runs it).
"""

from __future__ import annotations

import pathlib
import re
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "firmware" / "tests"))

from s32_fakes import Board  # noqa: E402


HEAP_LINE = re.compile(rb"booted: (\d+) bytes of heap free")


def _spi_device(framer):
    """A Qiling STM32F4 SPI peripheral whose data register talks to `framer(byte) -> reply`."""
    from qiling.hw.peripheral import QlPeripheral
    from qiling.hw.spi.stm32f4xx_spi import STM32F4xxSpi

    class DeviceSpi(STM32F4xxSpi):
        @QlPeripheral.monitor()
        def write(self, offset: int, size: int, value: int):
            if offset == self.struct.DR.offset:
                self.instance.DR = framer(value & 0xFF)
                return
            super().write(offset, size, value)

        @QlPeripheral.monitor()
        def read(self, offset: int, size: int) -> int:
            if offset == self.struct.DR.offset:
                return self.instance.DR
            return super().read(offset, size)

    return DeviceSpi


class TmcFramer:
    """Bytes on SPI2 into TMC5130 datagrams (the reply is fixed when a frame starts)."""

    def __init__(self, tmc):
        self.tmc = tmc
        self.tx = bytearray(5)
        self.rx = bytearray(5)
        self.n = 0

    def __call__(self, byte: int) -> int:
        if self.n == 0:
            self.tmc.reply(self.rx)
        self.tx[self.n] = byte
        out = self.rx[self.n]
        self.n += 1
        if self.n == 5:
            self.tmc.receive(*self.tx)
            self.n = 0
        return out


class TleFramer:
    """Bytes on SPI3 into TLE5012B transfers: two command bytes, then four reply bytes."""

    def __init__(self, tle):
        self.tle = tle
        self.buf = bytearray(4)
        self.command = 0
        self.n = 0

    def __call__(self, byte: int) -> int:
        n = self.n
        self.n = (n + 1) % 6
        if n < 2:
            self.command = (self.command << 8 | byte) & 0xFFFF
            return 0xFF
        if n == 2:
            self.tle.answer(self.command, self.buf)
        return self.buf[n - 2]


class EmulatedS32:
    """A composed flash file (image + configuration) booted; `run(rounds)` advances it."""

    def __init__(self, flash: pathlib.Path) -> None:
        import qiling.hw
        from qiling.core import Qiling
        from qiling.const import QL_ARCH, QL_OS, QL_VERBOSE
        from qiling.extensions.mcu.stm32f4 import stm32f401

        self.board = Board()
        self.tmc_frames = TmcFramer(self.board.tmc)
        self.tle_frames = TleFramer(self.board.tle)
        qiling.hw.S32TmcSpi = _spi_device(self.tmc_frames)
        qiling.hw.S32TleSpi = _spi_device(self.tle_frames)
        ql = Qiling([str(flash), 0x08000000], archtype=QL_ARCH.CORTEX_M, ostype=QL_OS.MCU, env=stm32f401,
                    verbose=QL_VERBOSE.DISABLED)
        for name in ("rcc", "flash interface", "pwr", "usart2", "gpioa", "gpiob", "gpioc", "gpioh", "i2c1",
                     "syscfg", "exti"):
            ql.hw.create(name)
        for label, struct in (("spi2", "S32TmcSpi"), ("spi3", "S32TleSpi")):
            _, base, kwargs = ql.hw.load_env(label.upper())
            ql.hw.create(label, struct, base, kwargs)
        ql.os.fast_mode = True
        self.ql = ql
        self.output = b""

    def run(self, rounds: int) -> bytes:
        """Advance by `rounds` of Qiling's fast-mode scheduler; returns the new UART output."""
        self.ql.run(count=rounds)
        got = self.ql.hw.usart2.recv()
        self.output += got
        return got

    def run_until(self, text: bytes, rounds: int = 200, step: int = 100000) -> bool:
        for _ in range(rounds):
            self.run(step)
            if text in self.output:
                return True
        return False


def main(flash: str) -> int:
    emu = EmulatedS32(pathlib.Path(flash))
    try:
        booted = emu.run_until(b"heap free")
    except Exception as exc:  # unicorn's fault (UcError), with the CPU's state: the emulation stopped
        regs = emu.ql.arch.regs
        sys.stderr.write(emu.output.decode(errors="replace"))
        sys.stderr.write(f"\nemulation stopped: {exc} at pc 0x{regs.read('pc'):08x} (lr 0x{regs.read('lr'):08x})\n")
        return 1
    if not booted:
        sys.stderr.write("the emulated S32 did not report its heap; its output:\n" + emu.output.decode(errors="replace"))
        return 1
    sys.stderr.write(emu.output.decode(errors="replace"))
    free = int(HEAP_LINE.search(emu.output).group(1))
    print(f"s32.heap_free_after_boot_kb {free / 1024:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
