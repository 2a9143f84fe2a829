"""An emulated uStepper S32: the built image (make s32-image) on Qiling's STM32F401 with the
chips the board carries, modelled at the register level (firmware/tests/s32_fakes.py):

    SPI2  a TMC5130 (40-bit datagrams, 5 bytes with the firmware's chip select low)
    SPI3  a TLE5012B (command word out, data and safety word in: 6 bytes a transfer)

and the joint's configuration in the last 4 KB of flash: the flash file is composed as
`bioscara flash --board s32` writes it (bioscara.s32flash.S32Image.composed). USART2 carries the
REPL and the firmware's log. Virtual time (EmulatedS32: one instruction a cycle at 84 MHz) makes
runs repeatable, but there is no timing fidelity: figures from here are functional (what the
firmware prints, its heap) or estimates (instructions per main-loop iteration), never times.

Needs Qiling 1.4.6 with unicorn 2.0.1.post1 (unicorn 2.1 breaks its memory map), which do not
share an environment with the project's: `make s32-emu` makes build/qiling-venv, and

    build/qiling-venv/bin/python tests/s32_emu.py FLASH.bin

boots FLASH.bin and serves it on stdin/stdout (`Server`: I2C transactions on the joint bus,
virtual time, the chips' registers, instruction counts), for the host's `Bus` in the project's
environment (tests/s32_bus.py, which tests/test_s32_emulated.py and bench/s32_image.py use).
"""

from __future__ import annotations

import json
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "firmware" / "tests"))

from s32_fakes import Board  # noqa: E402


BOOT_MS = 3000  # virtual time a boot may take (it takes about 940 ms)
AFTER_BOOT_MS = 50  # of the main loop after the boot, for a fault in its first iterations


# The transfer-complete flag of each DMA stream in LISR (streams 0-3) or HISR (4-7).
_DMA_TCIF = (5, 11, 21, 27)
_DMA_EN = 0x1
_DMA_TCIE = 0x10
_DMA_DIR_M2P = 0x40
_SPI_CR2_TXDMAEN = 0x2


def _spi_device(framer):
    """A Qiling STM32F4 SPI peripheral whose data register talks to `framer(byte) -> reply`.

    Transfers longer than a byte go through DMA (MicroPython's spi_transfer): when the firmware
    sets TXDMAEN, the DMA1 streams pointed at this data register move the whole transfer at once
    and raise their transfer-complete interrupts, as the real streams do once the last byte
    has shifted."""
    from qiling.hw.peripheral import QlPeripheral
    from qiling.hw.spi.stm32f4xx_spi import STM32F4xxSpi

    class DeviceSpi(STM32F4xxSpi):
        @QlPeripheral.monitor()
        def write(self, offset: int, size: int, value: int):
            if offset == self.struct.DR.offset:
                self.instance.DR = framer(value & 0xFF)
                return
            starts_dma = offset == self.struct.CR2.offset and value & ~self.instance.CR2 & _SPI_CR2_TXDMAEN
            super().write(offset, size, value)
            if starts_dma:
                self._dma_transfer()

        @QlPeripheral.monitor()
        def read(self, offset: int, size: int) -> int:
            if offset == self.struct.DR.offset:
                return self.instance.DR
            return super().read(offset, size)

        def _dma_transfer(self):
            dma = self.ql.hw.dma1
            data_register = self.base + self.struct.DR.offset
            streams = [(n, s) for n, s in enumerate(dma.instance.stream) if s.CR & _DMA_EN and s.PAR == data_register]
            tx = [s for _, s in streams if s.CR & _DMA_DIR_M2P]
            if not tx:
                return
            rx = [s for _, s in streams if not s.CR & _DMA_DIR_M2P]
            out = bytes(self.ql.mem.read(tx[0].M0AR, tx[0].NDTR))
            replies = bytes(framer(byte) for byte in out)
            if rx:
                self.ql.mem.write(rx[0].M0AR, replies[:rx[0].NDTR])
            for number, stream in streams:
                stream.NDTR = 0
                stream.CR &= ~_DMA_EN
                flag = 1 << _DMA_TCIF[number % 4]
                if number < 4:
                    dma.instance.LISR |= flag
                else:
                    dma.instance.HISR |= flag
                if stream.CR & _DMA_TCIE:
                    self.ql.hw.nvic.set_pending(dma.intn[number])

    return DeviceSpi


# STM32F4 I2C v1 registers (RM0368 section 18.6) as a target sees them.
_I2C_SR1_ADDR = 0x2
_I2C_SR1_STOPF = 0x10
_I2C_SR1_RXNE = 0x40
_I2C_SR1_TXE = 0x80
_I2C_SR1_AF = 0x400
_I2C_SR1_ERRORS = 0xDF00  # rc_w0: BERR ARLO AF OVR PECERR TIMEOUT SMBALERT
_I2C_SR2_BUSY = 0x2
_I2C_SR2_TRA = 0x4
_I2C_CR1_PE = 0x1
_I2C_CR2_ITERREN = 0x100
_I2C_CR2_ITEVTEN = 0x200
_I2C_CR2_ITBUFEN = 0x400


def _i2c_target():
    """Qiling's STM32F4 I2C with the target side its model lacks, as RM0368 section 18 describes
    a slave: a controller on the bus (`S32I2cTarget.post`) raises the events in the hardware's
    order, which MicroPython's i2cslave.c expects (write: ADDR RXNE*n STOPF; read: ADDR TXE*(n+1),
    then the controller's NACK sets AF, an error, with no STOPF after it; write then read: ADDR
    RXNE*n ADDR TXE*(m+1) AF), on the interrupt CR2 enables for each (event: ITEVTEN, TXE and RXNE
    also ITBUFEN; error: ITERREN), and the registers clear their flags as the manual says (ADDR:
    SR1 read while set, then SR2 read; RXNE: DR read; TXE: DR write; STOPF: SR1 read then CR1 write; errors:
    written 0), with SR2's BUSY from the START to the STOP (after a read, a bit after the
    controller's NACK, served or not) and TRA from a read's address match to the STOP (RM0368
    18.6.7). Not modelled: BTF and the byte the shift register holds while DR is full (the
    controller waits for every event instead: clock stretching without a limit), OVR/UNDR, BERR,
    ARLO, general call, dual addressing, PEC and SMBus."""
    from qiling.hw.i2c.stm32f4xx_i2c import STM32F4xxI2c
    from qiling.hw.peripheral import QlPeripheral

    class S32I2cTarget(STM32F4xxI2c):
        def __init__(self, ql, label, ev_intn=None, er_intn=None):
            super().__init__(ql, label, ev_intn=ev_intn, er_intn=er_intn)
            self.instance.SR1 = 0
            self.instance.SR2 = 0
            self.rx_byte = 0
            self.sent = bytearray()
            self._stop_seen = False
            self._addr_seen = False  # SR1 read with ADDR set: the SR2 read that follows clears it

        @QlPeripheral.monitor()
        def read(self, offset: int, size: int) -> int:
            regs = self.instance
            if offset == self.struct.SR1.offset:
                self._stop_seen = bool(regs.SR1 & _I2C_SR1_STOPF)
                self._addr_seen = bool(regs.SR1 & _I2C_SR1_ADDR)
                return regs.SR1
            if offset == self.struct.SR2.offset:
                if self._addr_seen:
                    regs.SR1 &= ~_I2C_SR1_ADDR
                    self._addr_seen = False
                return regs.SR2
            if offset == self.struct.DR.offset:
                regs.SR1 &= ~_I2C_SR1_RXNE
                return self.rx_byte
            return super().read(offset, size)

        @QlPeripheral.monitor()
        def write(self, offset: int, size: int, value: int):
            regs = self.instance
            if offset == self.struct.SR1.offset:
                regs.SR1 &= value | ~_I2C_SR1_ERRORS
            elif offset == self.struct.DR.offset:
                regs.SR1 &= ~_I2C_SR1_TXE
                self.sent.append(value & 0xFF)
            elif offset == self.struct.CR1.offset:
                regs.CR1 = value
                if self._stop_seen:
                    regs.SR1 &= ~_I2C_SR1_STOPF
            else:
                super().write(offset, size, value)

        def step(self):
            """Nothing: Qiling's step runs its controller-side transfers, which a target has not."""

        def address(self) -> int | None:
            """The 7-bit address the target answers, or None when it is off the bus."""
            regs = self.instance
            return (regs.OAR1 >> 1) & 0x7F if regs.CR1 & _I2C_CR1_PE else None

        def post(self, flags: int, transmitting: bool = False) -> None:
            """An event of the controller: set the flags and SR2's TRA for the direction (set at
            the address phase's end; a STOP, STOPF, clears it and BUSY) and raise the interrupt
            lines."""
            regs = self.instance
            if flags & _I2C_SR1_STOPF:
                regs.SR2 &= ~(_I2C_SR2_BUSY | _I2C_SR2_TRA)
            else:
                regs.SR2 = _I2C_SR2_BUSY | (_I2C_SR2_TRA if transmitting else 0)
            regs.SR1 |= flags
            self.raise_lines()

        def raise_lines(self) -> None:
            """Pend the interrupts whose lines SR1 and CR2 assert: they are levels, asserted while
            a flag is set and enabled (a target re-made mid-transaction is interrupted again when
            it enables them): the error line for AF (ITERREN), the event line for ADDR and STOPF
            (ITEVTEN) and for TXE and RXNE (ITEVTEN and ITBUFEN)."""
            regs = self.instance
            nvic = self.ql.hw.nvic
            if regs.SR1 & _I2C_SR1_ERRORS and regs.CR2 & _I2C_CR2_ITERREN:
                nvic.set_pending(self.er_intn)
            events = regs.SR1 & (_I2C_SR1_ADDR | _I2C_SR1_STOPF)
            if regs.CR2 & _I2C_CR2_ITBUFEN:
                events |= regs.SR1 & (_I2C_SR1_TXE | _I2C_SR1_RXNE)
            if events and regs.CR2 & _I2C_CR2_ITEVTEN:
                nvic.set_pending(self.ev_intn)

        def bus(self, busy: bool) -> None:
            """A START (busy) or STOP on the bus, whoever it addresses: SR2's BUSY is set from the
            START to the STOP, and the STOP clears TRA (RM0368 18.6.7)."""
            if busy:
                self.instance.SR2 |= _I2C_SR2_BUSY
            else:
                self.instance.SR2 &= ~(_I2C_SR2_BUSY | _I2C_SR2_TRA)

        def pending(self, flags: int) -> bool:
            return bool(self.instance.SR1 & flags)

    return S32I2cTarget


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


# Virtual time: one instruction is one cycle of the 84 MHz core (an estimate: the emulator has no
# timing fidelity). The CPU runs in slices of SLICE instructions; between slices the peripherals
# step, SysTick counts the slice down, pending interrupts are taken and the driver's ramp advances a
# millisecond at a time. A WFI ends its slice early: the core sleeps out the rest of it. A
# transaction on the joint bus runs the CPU in shorter steps: a byte's wire time each (i2c_transfer).
CORE_HZ = 84_000_000
CYCLES_PER_MS = CORE_HZ // 1000
SLICE = CYCLES_PER_MS // 8
_SYSTICK_ENABLE = 0x1
_SYSTICK_TICKINT = 0x2
_SYSTICK_COUNTFLAG = 0x10000
_UNMASK_STEPS = 64
I2C_STRETCH_LIMIT_S = 0.01  # the firmware serves an event in its interrupt, well within this
IRQ_SYSTICK = -1  # Qiling's numbering of the core's exceptions (qiling.arch.cortex_m_const.IRQ)
IRQ_HARD_FAULT = -13


class EmulatedS32:
    """A composed flash file (image + configuration) booted on Qiling's STM32F401, run in virtual
    time by a deterministic scheduler (`run_ms`).

    Qiling's own MCU loop (`ql.run`, fast mode) is not used: it slices by wall-clock time, so no
    two runs agree, and each `ql.run` call leaves its scheduler task registered with the program
    counter it was stopped at; the next call runs a new task beside it, and the stale one resumes
    the CPU at its old pc with the current registers (the fetch faults the first attempt met). Its
    NVIC also drops an interrupt raised while PRIMASK is set (MicroPython's WFI loops do exactly
    that) instead of keeping it pending, its ICER write disables every other interrupt of the word
    too, and its SysTick reloads a slice late.
    """

    def __init__(self, flash: pathlib.Path) -> None:
        import qiling.hw
        from qiling.core import Qiling
        from qiling.const import QL_ARCH, QL_OS, QL_VERBOSE
        from qiling.extensions.mcu.stm32f4 import stm32f401
        from unicorn import arm_const

        self.board = Board()
        self.tmc_frames = TmcFramer(self.board.tmc)
        self.tle_frames = TleFramer(self.board.tle)
        qiling.hw.S32TmcSpi = _spi_device(self.tmc_frames)
        qiling.hw.S32TleSpi = _spi_device(self.tle_frames)
        ql = Qiling([str(flash), 0x08000000], archtype=QL_ARCH.CORTEX_M, ostype=QL_OS.MCU, env=stm32f401,
                    verbose=QL_VERBOSE.DISABLED)
        qiling.hw.S32I2cTarget = _i2c_target()
        for name in ("rcc", "flash interface", "pwr", "usart2", "gpioa", "gpiob", "gpioc", "gpioh",
                     "syscfg", "exti", "dma1"):
            ql.hw.create(name)
        ql.hw.stepable.pop("dma1")  # its streams move a byte per step; the SPI models do whole transfers
        for label, struct in (("spi2", "S32TmcSpi"), ("spi3", "S32TleSpi"), ("i2c1", "S32I2cTarget")):
            _, base, kwargs = ql.hw.load_env(label.upper())
            ql.hw.create(label, struct, base, kwargs)
        # S0-S15 and FPSCR: what a Cortex-M4F stacks on exception entry (Qiling stacks none)
        self._fp_stacked = [arm_const.UC_ARM_REG_S0 + i for i in range(16)] + [arm_const.UC_ARM_REG_FPSCR]
        ql.hw.systick.step = self._systick_step
        ql.hw.nvic.step = self._take_interrupts
        ql.hw.nvic.triggers = [(register, self._disable_interrupt if register.offset == ql.hw.nvic.struct.ICER.offset
                                    else action) for register, action in ql.hw.nvic.triggers]
        self.ql = ql
        self.cycles = 0
        self._stepping = SLICE  # cycles the next SysTick step counts down
        self.output = b""

    def run_ms(self, ms: int) -> bytes:
        """Advance `ms` milliseconds of virtual time; returns the new UART output."""
        return self.run_cycles(ms * CYCLES_PER_MS)

    def run_cycles(self, cycles: int) -> bytes:
        """Advance `cycles` core clocks of virtual time (in slices); returns the new UART output."""
        while cycles > 0:
            self._run(min(cycles, SLICE))
            cycles -= SLICE
        got = self.ql.hw.usart2.recv()
        self.output += got
        return got

    def _run(self, instructions: int) -> None:
        """Step the peripherals, run the CPU `instructions` (cycles), then the board's millisecond
        ticks the time crossed."""
        from unicorn import UcError

        self._stepping = instructions
        self.ql.hw.step()
        try:
            self.ql.uc.emu_start(self.ql.arch.effective_pc, 0, 0, instructions)
        except UcError as exc:
            raise EmulationFault(self, exc) from exc
        ms_before = self.cycles // CYCLES_PER_MS
        self.cycles += instructions
        self._reach_unmasked()
        for _ in range(self.cycles // CYCLES_PER_MS - ms_before):
            self.board.tick_ms()

    def i2c_transfer(self, address: int, write: bytes | None, read_len: int, speed_hz: int = 400_000) -> bytes:
        """One transaction of a controller on the joint bus (I2C1), as `Bus.transfer` makes it:
        write `write`, repeated START, read `read_len` bytes, STOP. OSError when nobody answers
        the address (NACK); TimeoutError when the target stops serving its events.

        Virtual time: each event (address, data byte, NACK) takes one byte's wire time at
        `speed_hz` (9 clocks), and as many more as the target holds it unserved (on the wire:
        SCL stretched), up to I2C_STRETCH_LIMIT_S."""
        target = self.ql.hw.i2c1
        target.bus(True)
        try:
            return self._i2c_phases(address, write, read_len, speed_hz)
        finally:
            target.bus(False)

    def _i2c_phases(self, address: int, write: bytes | None, read_len: int, speed_hz: int) -> bytes:
        target = self.ql.hw.i2c1
        if target.address() != address:
            self.run_cycles(self._byte_cycles(speed_hz))  # the address byte, not acknowledged
            raise OSError(f"no I2C target answers 0x{address:02x}")
        if write is not None:
            self._i2c_event(_I2C_SR1_ADDR, speed_hz)
            for byte in write:
                target.rx_byte = byte
                self._i2c_event(_I2C_SR1_RXNE, speed_hz)
            if not read_len:
                self._i2c_event(_I2C_SR1_STOPF, speed_hz)
                return b""
        target.sent.clear()
        self._i2c_event(_I2C_SR1_ADDR, speed_hz, transmitting=True)
        for _ in range(read_len + 1):  # the last TXE comes before the controller's NACK
            self._i2c_event(_I2C_SR1_TXE, speed_hz, transmitting=True)
        # The controller's NACK, then its STOP a bit later, whether or not the target has served
        # the AF yet: no clock is stretched after a NACK.
        target.post(_I2C_SR1_AF, transmitting=True)
        self._run(self._byte_cycles(speed_hz) // 9)
        target.bus(False)
        self._await_served(_I2C_SR1_AF, speed_hz)
        if len(target.sent) < read_len:
            raise TimeoutError(f"the target sent {len(target.sent)} of {read_len} bytes")
        return bytes(target.sent[:read_len])

    @staticmethod
    def _byte_cycles(speed_hz: int) -> int:
        return CORE_HZ * 9 // speed_hz

    def _i2c_event(self, flags: int, speed_hz: int, transmitting: bool = False) -> None:
        self.ql.hw.i2c1.post(flags, transmitting)
        self._await_served(flags, speed_hz)

    def _await_served(self, flags: int, speed_hz: int) -> None:
        """Run a byte's time at a time until the target has cleared `flags`, re-raising its
        interrupt lines, up to I2C_STRETCH_LIMIT_S."""
        target = self.ql.hw.i2c1
        byte = self._byte_cycles(speed_hz)
        for _ in range(int(I2C_STRETCH_LIMIT_S * CORE_HZ) // byte + 1):
            self._run(byte)
            if not target.pending(flags):
                return
            target.raise_lines()
        raise TimeoutError(f"the I2C target left event 0x{flags:x} unserved")

    def run_until(self, text: bytes, ms: int) -> bool:
        """Run until the UART output holds `text`, for at most `ms` of virtual time."""
        for _ in range(ms):
            if text in self.output:
                return True
            self.run_ms(1)
        return text in self.output

    def _reach_unmasked(self) -> None:
        """With an interrupt pending but masked (MicroPython sleeps in `cpsid i; wfi; msr PRIMASK`),
        step on until the mask lifts, so the interrupt is taken where the hardware takes it rather
        than a slice later, every slice."""
        nvic = self.ql.hw.nvic
        for _ in range(_UNMASK_STEPS):
            if not nvic.intrs or any(self._unmasked(n) for n in nvic.intrs):
                return
            self.ql.uc.emu_start(self.ql.arch.effective_pc, 0, 0, 1)

    def _systick_step(self) -> None:
        """SysTick counts down the step's core clocks, reloading from LOAD as the hardware does."""
        tick = self.ql.hw.systick.instance
        if not tick.CTRL & _SYSTICK_ENABLE:
            return
        value = tick.VAL - self._stepping
        if value < 0:
            value %= tick.LOAD + 1
            tick.CTRL |= _SYSTICK_COUNTFLAG
            if tick.CTRL & _SYSTICK_TICKINT:
                self.ql.hw.nvic.set_pending(IRQ_SYSTICK)
        tick.VAL = value

    def _take_interrupts(self) -> None:
        """Take the pending interrupts the core's masks allow, highest priority first; the others
        stay pending (Qiling's NVIC would drop them)."""
        nvic = self.ql.hw.nvic
        arch = self.ql.arch
        while nvic.intrs:
            pending = sorted(set(nvic.intrs), key=nvic.get_priority)
            taken = next((n for n in pending if self._unmasked(n)), None)
            if taken is None:
                nvic.intrs = pending
                return
            nvic.intrs = [n for n in pending if n != taken]
            nvic.clear_pending(taken)
            fp = [self.ql.uc.reg_read(reg) for reg in self._fp_stacked]
            arch.interrupt_handler(self.ql, taken)
            if arch.regs.read("ipsr"):
                raise EmulationFault(self, RuntimeError(f"interrupt {taken} did not return"))
            for reg, value in zip(self._fp_stacked, fp):
                self.ql.uc.reg_write(reg, value)

    def _disable_interrupt(self, irq: int) -> None:
        """NVIC ICER: disable `irq` alone (Qiling's clears every other enable bit of its word but
        the low five: a DMA stream's interrupt disabled at the end of an SPI transfer would
        disable the joint bus's I2C1 event interrupt)."""
        nvic = self.ql.hw.nvic
        if irq < 0:
            self.ql.hw.scb.disable(irq)
            return
        word, bit = irq >> nvic.OFFSET, 1 << (irq & nvic.MASK)
        nvic.instance.ISER[word] &= ~bit
        nvic.instance.ICER[word] &= ~bit

    def _unmasked(self, irq: int) -> bool:
        regs = self.ql.arch.regs
        basepri = regs.read("basepri") & 0xF0
        if basepri and basepri <= self.ql.hw.nvic.get_priority(irq):
            return False
        return not (irq > IRQ_HARD_FAULT and regs.read("primask") & 1)


class EmulationFault(Exception):
    """The emulated CPU stopped (unicorn's fault): where, with the symbols' addresses."""

    def __init__(self, emu: EmulatedS32, cause: Exception) -> None:
        regs = emu.ql.arch.regs
        super().__init__(f"{cause} at pc 0x{regs.read('pc'):08x} (lr 0x{regs.read('lr'):08x}) "
                         f"after {emu.cycles} cycles")


class InstructionCount:
    """Instructions executed from `start` to `stop`: all of them, those in the joint bus's
    interrupts (I2C1's event and error handlers, the firmware's Python handler included), and the
    main loop's iterations when the image's ELF is known. An iteration is app.run's
    `time.ticks_add(next_us, 1000)`: a call of the C function time_ticks_add with delta 1000 (the
    small int 1000 is 2001 in r1). Slow (a Python hook on every instruction): for the estimates
    only."""

    def __init__(self, emu: EmulatedS32, elf: pathlib.Path) -> None:
        self.emu = emu
        target = emu.ql.hw.i2c1
        self.i2c_exceptions = (16 + target.ev_intn, 16 + target.er_intn)  # IPSR holds the exception number
        self.elf = elf
        self.total = 0
        self.in_i2c = 0
        self.iterations = 0
        self._hook = None

    def start(self) -> None:
        from unicorn import UC_HOOK_CODE
        from unicorn.arm_const import UC_ARM_REG_IPSR, UC_ARM_REG_R1

        self.total = self.in_i2c = self.iterations = 0
        ticks_add = _symbol(self.elf, "time_ticks_add.lto_priv.0") if self.elf.exists() else None

        def count(uc, address, size, _):
            self.total += 1
            if uc.reg_read(UC_ARM_REG_IPSR) in self.i2c_exceptions:
                self.in_i2c += 1
            elif address == ticks_add and uc.reg_read(UC_ARM_REG_R1) == 2001:
                self.iterations += 1

        self._hook = self.emu.ql.uc.hook_add(UC_HOOK_CODE, count)
        self.emu.ql.uc.ctl_flush_tb()  # blocks translated before the hook would run uncounted

    def stop(self) -> None:
        if self._hook is not None:
            self.emu.ql.uc.hook_del(self._hook)
            self.emu.ql.uc.ctl_flush_tb()
            self._hook = None


def _symbol(elf: pathlib.Path, name: str) -> int:
    symbols = subprocess.run(["arm-none-eabi-nm", str(elf)], capture_output=True, text=True, check=True).stdout
    return next(int(line.split()[0], 16) for line in symbols.splitlines() if line.endswith(" " + name))


# The TMC5130 registers `board` reports (datasheet names; ustepper-model.md section 2's units).
TMC_REGISTERS = {"GCONF": 0x00, "IHOLD_IRUN": 0x10, "RAMPMODE": 0x20, "XACTUAL": 0x21, "AMAX": 0x26,
                 "VMAX": 0x27, "DMAX": 0x28, "XTARGET": 0x2D, "CHOPCONF": 0x6C}


class Server:
    """The emulated S32 served on a pipe, one JSON object a line each way (tests/s32_bus.py is
    the other end). After the boot it writes {"booted": true|false, ...}; then each request
    {"op": ...} gets one reply. Every reply carries "us" (virtual time since reset) and "log"
    (the UART output since the last reply); a fault of the emulated CPU replies {"fault": why}
    and ends the server. Requests:

        transfer  address, write (hex or null), read, speed_hz -> data (hex), or nack / timeout
        run       us: advance virtual time
        board     -> the TMC5130's registers (TMC_REGISTERS), VACTUAL, its datagram count, the
                     rotor's position and wall (usteps)
        wall      position (usteps or null), side (+1: stops travel upward, -1 downward)
        count     on: start (true) or stop (false) counting instructions -> total, in_i2c,
                  iterations (of the main loop: needs firmware.elf beside the flash file, else 0)
    """

    def __init__(self, flash: pathlib.Path) -> None:
        self.flash = flash
        self.emu = EmulatedS32(flash)
        self.count = InstructionCount(self.emu, flash.with_name("firmware.elf"))
        self._logged = 0

    def reply(self, message: dict) -> None:
        emu = self.emu
        message["us"] = emu.cycles * 1_000_000 // CORE_HZ
        message["log"] = emu.output[self._logged:].decode(errors="replace")
        self._logged = len(emu.output)
        sys.stdout.write(json.dumps(message) + "\n")
        sys.stdout.flush()

    def boot(self) -> bool:
        booted = self.emu.run_until(b"heap free", BOOT_MS)
        if booted:
            self.emu.run_ms(AFTER_BOOT_MS)
        self.reply({"booted": booted})
        return booted

    def handle(self, request: dict) -> dict:
        emu = self.emu
        op = request["op"]
        if op == "transfer":
            write = None if request["write"] is None else bytes.fromhex(request["write"])
            try:
                data = emu.i2c_transfer(request["address"], write, request["read"], request["speed_hz"])
            except TimeoutError as exc:
                return {"timeout": str(exc)}
            except OSError as exc:
                return {"nack": str(exc)}
            finally:
                self.emu.run_cycles(0)  # collect the UART output the transaction caused
            return {"data": data.hex()}
        if op == "run":
            emu.run_cycles(request["us"] * CYCLES_PER_MS // 1000)
            return {}
        if op == "board":
            tmc, rotor = emu.board.tmc, emu.board.rotor
            registers = {name: tmc.regs[address] for name, address in TMC_REGISTERS.items()}
            return {"tmc": registers, "VACTUAL": tmc.v, "datagrams": tmc.frames, "rotor": rotor.position,
                    "wall": rotor.wall}
        if op == "wall":
            emu.board.rotor.wall = request["position"]
            emu.board.rotor.wall_side = request["side"]
            return {}
        if op == "count":
            if request["on"]:
                self.count.start()
                return {}
            self.count.stop()
            return {"total": self.count.total, "in_i2c": self.count.in_i2c, "iterations": self.count.iterations}
        return {"error": f"no request {op!r}"}

    def serve(self) -> int:
        try:
            if not self.boot():
                return 1
            for line in sys.stdin:
                if line.strip():
                    self.reply(self.handle(json.loads(line)))
        except EmulationFault as exc:
            self.reply({"fault": str(exc)})
            return 1
        return 0


def main(flash: str) -> int:
    """Boot `flash` and serve it on stdin/stdout until stdin closes."""
    return Server(pathlib.Path(flash)).serve()


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
