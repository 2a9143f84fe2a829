"""Fakes and references shared by the Pico backend tests (test_pico_*.py): the single-wire UART
bus with a TMC2209 behind it, the AS5600 registers, the RP2040 I2C and PIO registers, the PIO state
machine, pins, and a Bench that wires a PicoStepper to them with a rotor that follows the pulses."""

import sys

from joint.pico import as5600 as enc
from joint.pico import stepgen as sg
from joint.pico import tmc2209 as tmc
from joint.pico.as5600 import AS5600
from joint.pico.motor import PicoStepper
from joint.pico.stepgen import StepGenerator
from joint.pico.tmc2209 import TMC2209, TMCError
from joint.motion.fixed import ANGLE_Q, RPM_Q, STEPS_Q, to_q
from joint.sim.clock import VirtualClock

RPM = 1 << RPM_Q  # the HAL's fixed-point units (hal.py)
FS = 1 << STEPS_Q


def deg(motor):
    return motor.angle_moved() / (1 << ANGLE_Q)


# ---- independent references ----

def _reverse_bits(b):
    r = 0
    for _ in range(8):
        r = (r << 1) | (b & 1)
        b >>= 1
    return r


def ref_crc(data):
    """CRC-8/ATM (poly 0x07, MSB first) over bit-reversed bytes: the TMC's LSB-first CRC, derived
    differently from the firmware's loop."""
    crc = 0
    for b in data:
        crc ^= _reverse_bits(b)
        for _ in range(8):
            crc = ((crc << 1) ^ 0x07) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc


def raises(exc_type, fn, *args):
    try:
        fn(*args)
    except exc_type as exc:
        return exc
    raise AssertionError("%s not raised" % exc_type.__name__)


# ---- fakes ----

class FakeTMCBus:
    """machine.UART on the PDN_UART wire: our bytes come back as echo, a TMC2209 answers reads."""

    def __init__(self, node=0):
        self.node = node
        self.regs = {tmc.IOIN: 0x21000040, tmc.CHOPCONF: 0x10000053, tmc.PWMCONF: 0xC10D0024,
                     tmc.GCONF: 0x101}
        self.ifcnt = 0
        self.sent = []
        self.writes = []  # (reg, value) accepted
        self.rx = bytearray()
        self.echo = True
        self.silent = False
        self.corrupt = False
        self.drop_writes = False

    def any(self):
        return len(self.rx)

    def readinto(self, buf):
        n = min(len(buf), len(self.rx))
        for i in range(n):
            buf[i] = self.rx[i]
        self.rx = self.rx[n:]
        return n or None

    def write(self, data):
        data = bytes(data)
        self.sent.append(data)
        if self.echo:
            self.rx += data
        if ref_crc(data[:-1]) != data[-1] or data[1] != self.node:
            return
        reg = data[2] & 0x7F
        if len(data) == 8 and data[2] & 0x80:
            if not self.drop_writes:
                value = (data[3] << 24) | (data[4] << 16) | (data[5] << 8) | data[6]
                self.regs[reg] = value
                self.writes.append((reg, value))
                self.ifcnt = (self.ifcnt + 1) & 0xFF
        elif len(data) == 4 and not self.silent:
            value = self.ifcnt if reg == tmc.IFCNT else self.regs.get(reg, 0)
            reply = bytearray([0x05, 0xFF, reg, value >> 24 & 0xFF, value >> 16 & 0xFF,
                               value >> 8 & 0xFF, value & 0xFF, 0])
            reply[7] = ref_crc(reply[:7])
            if self.corrupt:
                reply[5] ^= 0x10
            self.rx += reply


class FakeAS5600Bus:
    """machine.I2C with an AS5600 at 0x36."""

    def __init__(self):
        self.raw = 0
        self.status = 0x20  # magnet detected
        self.conf = bytearray(2)
        self.fail = False
        self.reads = 0
        self.pointer = 0  # the address pointer: stays on RAW ANGLE, advances past other registers

    def readfrom_mem_into(self, addr, reg, buf):
        if self.fail or addr != 0x36:
            raise OSError(5)
        self.pointer = reg
        self.readfrom_into(addr, buf)

    def readfrom_into(self, addr, buf):
        if self.fail or addr != 0x36:
            raise OSError(5)
        self.reads += 1
        reg = self.pointer
        if reg == enc.RAW_ANGLE:
            buf[0] = (self.raw >> 8) | 0xF0  # the unused high nibble must be masked
            buf[1] = self.raw & 0xFF
            return
        for i in range(len(buf)):
            buf[i] = 0xFF
        if reg == enc.STATUS:
            buf[0] = self.status
        elif reg == enc.CONF:
            buf[0], buf[1] = self.conf[0], self.conf[1]
        self.pointer = reg + len(buf)

    def writeto_mem(self, addr, reg, buf):
        if self.fail or addr != 0x36:
            raise OSError(5)
        if reg == enc.CONF:
            self.conf[0], self.conf[1] = buf[0], buf[1]


class FakeI2CRegisters:
    """The DW_apb_i2c registers (32-bit word indices) in controller mode in front of a
    FakeAS5600Bus, for the queued reads: a read queued with STOP happens at once (pointer-less, as
    on the wire), or with `hold` stays on the wire until finish(). A failing bus aborts it (NACK).
    CPython only: viper takes an address or a buffer, not this object, under MicroPython."""

    typecode = "I"  # micro.ptr32 passes it through

    def __init__(self, bus):
        self.bus = bus
        self.rx = []
        self.cmds = []
        self.aborted = 0  # TX_ABRT_SOURCE
        self.hold = False
        self.queued = 0  # reads queued

    def __getitem__(self, i):
        if i == enc._RXFLR:
            return len(self.rx)
        if i == enc._DATA_CMD:
            return self.rx.pop(0)
        if i == enc._RAW_INTR_STAT:
            return enc._TX_ABRT if self.aborted else 0
        if i == enc._TX_ABRT_SOURCE:
            return self.aborted
        if i == enc._CLR_TX_ABRT:
            self.aborted = 0
            return 1
        raise AssertionError("register word %d" % i)

    def __setitem__(self, i, value):
        assert i == enc._DATA_CMD and value & enc._CMD_READ
        assert not self.aborted, "TX FIFO held flushed until the abort is cleared"
        self.cmds.append(value)
        if value & enc._CMD_STOP:
            self.queued += 1
            if not self.hold:
                self.finish()

    def finish(self):
        if not self.cmds:
            return
        n = len(self.cmds)
        self.cmds = []
        if self.bus.fail:
            self.aborted = 1  # ABRT_7B_ADDR_NOACK
            return
        buf = bytearray(n)
        self.bus.readfrom_into(0x36, buf)
        self.rx += [buf[0] | 0x400] + list(buf[1:])  # the emulator's FIRST_DATA_BYTE mark


class FakePIORegisters:
    """The FIFO registers of a PIO block (32-bit word indices) whose state machine `index` is a
    FakeSM. CPython only, as FakeI2CRegisters."""

    typecode = "I"

    def __init__(self, sm, index):
        self.sm = sm
        self.index = index
        self.words = 0  # words through TXF and RXF

    def __getitem__(self, i):
        if i == sg._FSTAT:
            return 0 if self.sm.rx else 1 << (sg._RXEMPTY + self.index)
        assert i == sg._RXF + self.index
        self.words += 1
        return self.sm.get()

    def __setitem__(self, i, value):
        assert i == sg._TXF + self.index
        self.words += 1
        self.sm.put(value)


MICROPYTHON = sys.implementation.name == "micropython"


class FakeSM:
    """rp2.StateMachine: words wait in `tx` until finish() acknowledges them like the PIO does."""

    def __init__(self):
        self.tx = []
        self.rx = []

    def put(self, word):
        assert len(self.tx) < 4, "put() would block"
        self.tx.append(word)

    def rx_fifo(self):
        return len(self.rx)

    def get(self):
        return self.rx.pop(0)

    def finish(self):
        """Complete every queued burst; returns the pulses emitted (signed)."""
        pulses = 0
        while self.tx:
            word = self.tx.pop(0)
            pulses += sg.burst_pulses(word)
            self.rx.append(word)
        return pulses


class FakePin:
    def __init__(self, level=1):
        self.level = level

    def value(self, v=None):
        if v is None:
            return self.level
        self.level = v


class Bench:
    """A PicoStepper on fakes plus a rotor that follows the emitted pulses at 1 ms per tick."""

    def __init__(self, **kw):
        self.uart = FakeTMCBus()
        self.i2c = FakeAS5600Bus()
        self.sm = FakeSM()
        self.pin = FakePin()
        self.clock = kw.pop("clock", None) or VirtualClock()
        self.wiring = 1  # +1: positive pulses turn the encoder positive (shaft bit off)
        self.blocked = False
        self.rotor = 0.0  # usteps
        self.emitted = 0  # usteps of pulses the PIO sent
        self.offset = 1000  # raw angle at rotor 0: the magnet is not at the sensor's zero
        pio = FakePIORegisters(self.sm, 2) if kw.pop("pio", False) else 0
        self.steps = StepGenerator(self.sm, kw.pop("microsteps", 256), pio=pio, index=2)
        self.regs = FakeI2CRegisters(self.i2c) if kw.pop("queued", False) else 0
        self.motor = PicoStepper(TMC2209(self.uart), AS5600(self.i2c, regs=self.regs), self.steps, self.pin,
                                 self.clock, **kw)
        self._shaft = False
        self._encode()

    def _encode(self):
        self.i2c.raw = (int(self.rotor // 12.5) + self.offset) % 4096

    def begin(self):
        self.motor.begin()
        return self

    def tick(self, n=1):
        for _ in range(n):
            self.clock.advance(1000)
            pulses = self.sm.finish()
            self.emitted += pulses * self.steps.upp
            shaft = tmc.SHAFT & self.uart.regs.get(tmc.GCONF, 0)
            direction = -self.wiring if shaft else self.wiring
            if not self.blocked:
                self.rotor += direction * pulses * self.steps.upp
            self._encode()
            self.motor.update()

    def run_until_reached(self, limit=20000):
        for i in range(limit):
            self.tick()
            if self.motor.position_reached():
                return i + 1
        raise AssertionError("move did not finish")
