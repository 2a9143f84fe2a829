"""Pico backend (TMC2209 + AS5600 + PIO step/dir) against datasheet facts, with fake hardware.

Plain functions and bare asserts: this module runs under CPython (pytest) and the MicroPython unix
port (mprun.py). The fakes model the single-wire UART bus (echo + driver replies with their own
register file), the AS5600 registers, the PIO state machine and, for the motor tests, a rotor that
follows the pulses unless the test blocks or slips it.
"""

import sys

from joint.pico import as5600 as enc
from joint.pico import stepgen as sg
from joint.pico import tmc2209 as tmc
from joint.pico import tmc2209_setup as tmc_setup
from joint.pico.as5600 import AS5600
from joint.pico.motor import PicoStepper
from joint.pico.motor_config import DEFAULTS, validate_motor_config
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
        self.clock = VirtualClock()
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


# ---- TMC2209 datagrams ----

def test_crc8_matches_datasheet_algorithm_and_known_datagrams():
    buf = bytearray(8)
    tmc.pack_read(buf, 0, tmc.GCONF)
    assert bytes(buf[:4]) == bytes([0x05, 0x00, 0x00, 0x48])  # GCONF read request, node 0
    tmc.pack_write(buf, 0, tmc.CHOPCONF, 0x10000053)  # its reset value, as captured on a bus
    assert bytes(buf) == bytes([0x05, 0x00, 0xEC, 0x10, 0x00, 0x00, 0x53, 0x9C])
    assert tmc.crc8(bytes([0x55, 0x00, 0x06]), 3) == 0xE8  # sync nibble with reserved bits set
    for node in range(4):
        for reg in (0x00, 0x10, 0x6C, 0x70, 0x7F):
            for value in (0, 1, 0x80000000, 0xFFFFFFFF, 0x12345678):
                tmc.pack_write(buf, node, reg, value)
                assert buf[7] == ref_crc(buf[:7])
                assert buf[1] == node and buf[2] == reg | 0x80


def test_write_datagram_is_msb_first_with_write_bit():
    buf = bytearray(8)
    tmc.pack_write(buf, 3, tmc.IHOLD_IRUN, 0x00011F08)
    assert bytes(buf[:7]) == bytes([0x05, 0x03, 0x90, 0x00, 0x01, 0x1F, 0x08])


def test_reply_parsing_of_a_captured_ioin_read():
    reply = bytes([0x05, 0xFF, 0x06, 0x21, 0x00, 0x02, 0x41, 0x9D])
    value = tmc.parse_reply(reply, 0, tmc.IOIN)
    assert value == 0x21000241 and value >> 24 == tmc.VERSION
    framed = bytes([0x55, 0x00, 0x06, 0xE8]) + reply  # echo of the request first
    assert tmc.parse_reply(framed, 4, tmc.IOIN) == 0x21000241


def test_reply_parsing_rejects_corruption():
    good = bytearray([0x05, 0xFF, 0x06, 0x21, 0x00, 0x02, 0x41, 0x9D])
    bad = bytearray(good)
    bad[5] ^= 0x01
    assert "CRC" in str(raises(TMCError, tmc.parse_reply, bad, 0, tmc.IOIN))
    bad = bytearray(good)
    bad[1] = 0x00  # not addressed to the master
    raises(TMCError, tmc.parse_reply, bad, 0, tmc.IOIN)
    raises(TMCError, tmc.parse_reply, good, 0, tmc.GCONF)  # answer for another register
    bad = bytearray(good)
    bad[0] = 0x00
    raises(TMCError, tmc.parse_reply, bad, 0, tmc.IOIN)


def test_register_access_over_the_single_wire_bus():
    bus = FakeTMCBus(node=2)
    drv = TMC2209(bus, 2)
    assert drv.read(tmc.IOIN) == 0x21000040
    assert bus.sent[-1] == bytes([0x05, 0x02, 0x06, ref_crc([0x05, 0x02, 0x06])])
    drv.write(tmc.GCONF, 0x1C0)
    assert bus.regs[tmc.GCONF] == 0x1C0 and bus.ifcnt == 1 and bus.any() == 0
    bus.rx += b"\x01\x02"  # stale bytes on the line are drained first
    assert drv.read(tmc.IFCNT) == 1
    bus.corrupt = True
    raises(TMCError, drv.read, tmc.GCONF)
    bus.corrupt = False
    bus.silent = True
    assert "no reply" in str(raises(TMCError, drv.read, tmc.GCONF))
    bus.silent = False
    bus.echo = False
    assert "echo" in str(raises(TMCError, drv.write, tmc.GCONF, 0))


def test_register_fields():
    assert tmc.gconf(False) == 0x1C0  # pdn_disable, mstep_reg_select, multistep_filt
    assert tmc.gconf(True) == 0x1C8  # + shaft
    assert tmc.gconf(False) & (tmc.I_SCALE_ANALOG | tmc.EN_SPREADCYCLE) == 0
    assert tmc.ihold_irun(13, 13) == 0x0D0D
    assert tmc.ihold_irun(0, 31, 15) == 0x000F1F00
    assert [tmc_setup.mres(m) for m in (256, 128, 64, 32, 16, 8, 4, 2, 1)] == list(range(9))
    for bad in (0, 3, 12, 512):
        raises(ValueError, tmc_setup.mres, bad)
    chop = tmc_setup.chopconf(0x10000053, 16, 1)
    assert chop == 0x10000053 | (4 << 24) | (1 << 17)  # MRES=4, vsense, intpol kept, chopper kept
    assert tmc_setup.chopconf(0x0F000000, 256, 0) == 0x10000003  # TOFF=0 would disable the bridges
    assert tmc.pwmconf(0xC10D0024, tmc.FREEWHEEL_SHORT_LS) == 0xC12D0024
    assert tmc.pwmconf(0xC13D0024, tmc.FREEWHEEL_NORMAL) == 0xC10D0024


def test_drv_status_decode():
    s = tmc.decode_drv_status((1 << 31) | (1 << 30) | (17 << 16) | (1 << 8) | 0x41)
    assert s["stst"] and s["stealth"] and s["cs_actual"] == 17 and s["t120"]
    assert s["otpw"] and s["ola"] and not s["ot"] and not s["s2ga"] and not s["olb"]
    assert not any(v for k, v in tmc.decode_drv_status(0).items())


def test_current_formula_against_the_datasheet_sense_resistor_table():
    # R_sense -> RMS current at CS=31, vsense=0 (TMC2209 datasheet, "Selecting sense resistors")
    for rsense, amps in ((1.00, 0.23), (0.47, 0.47), (0.22, 0.96), (0.15, 1.35), (0.10, 1.92)):
        assert abs(tmc_setup.rms_current(31, 0, rsense) - amps) < 0.006
    assert abs(tmc_setup.rms_current(15, 1, 0.11) / tmc_setup.rms_current(31, 1, 0.11) - 0.5) < 1e-9


def test_full_scale_picks_vsense_and_cs():
    assert tmc_setup.current_scale(0.11, 1.5) == (0, 26)  # too much for vsense=1 (0.98 A max)
    assert tmc_setup.current_scale(0.11, 0.8) == (1, 25)  # fits vsense=1: finer steps
    for rsense, amps in ((0.11, 1.5), (0.11, 0.8), (0.22, 0.5)):
        vsense, cs = tmc_setup.current_scale(rsense, amps)
        assert tmc_setup.rms_current(cs, vsense, rsense) <= amps < tmc_setup.rms_current(cs + 1, vsense, rsense)
    raises(ValueError, tmc_setup.current_scale, 0.11, 1.9)
    raises(ValueError, tmc_setup.current_scale, 0.11, 0.01)


def test_percent_to_current_scale_matches_the_library():
    # setCurrent(p): IRUN = ceil(0.31 p), out-of-range input gives 16 (ustepper-model.md 4.3)
    library = {0: 0, 20: 7, 25: 8, 40: 13, 50: 16, 99: 31, 100: 31, 101: 16, -1: 16}
    for percent, cs in library.items():
        assert tmc.percent_to_cs(percent, 31) == cs, percent
    assert tmc.percent_to_cs(100, 26) == 26
    assert tmc.percent_to_cs(40, 26) == 11  # ceil(10.4)


def test_brake_modes_map_to_ihold_and_freewheel():
    assert tmc.brake_settings(0, 31) == (0, tmc.FREEWHEEL_OPEN)
    assert tmc.brake_settings(1, 31) == (0, tmc.FREEWHEEL_SHORT_LS)
    assert tmc.brake_settings(2, 31) == (8, tmc.FREEWHEEL_NORMAL)  # 25 % -> 9/32
    assert tmc.brake_settings(7, 31) == (8, tmc.FREEWHEEL_NORMAL)  # unknown: keep holding


def test_timing_registers():
    assert tmc_setup.tpowerdown(0.524) == 24  # 24 * 2^18 / 12 MHz = 0.524 s
    assert tmc_setup.tpowerdown(100) == 255
    assert tmc_setup.tpwmthrs(2000.0) == 6000  # 12 MHz / 2000 usteps/s


# ---- AS5600 ----

def test_as5600_raw_angle_and_magnet_status():
    bus = FakeAS5600Bus()
    sensor = AS5600(bus)
    bus.raw = 4095
    assert sensor.read_raw() == 4095
    bus.raw = 0x123
    assert sensor.read_raw() == 0x123
    assert enc.decode_status(0x20) == (True, False, False)
    assert enc.decode_status(0x30) == (True, True, False)
    assert enc.decode_status(0x28) == (True, False, True)
    assert enc.decode_status(0x00) == (False, False, False)
    bus.status = 0x18
    assert enc.decode_status(sensor.status()) == (False, True, True)


def test_as5600_unwrap_across_zero_both_directions():
    assert enc.unwrap(4095, 0) == 1
    assert enc.unwrap(0, 4095) == -1
    assert enc.unwrap(4000, 100) == 196
    assert enc.unwrap(100, 4000) == -196
    assert enc.unwrap(10, 10) == 0
    assert enc.unwrap(0, 2048) == 2048 and enc.unwrap(0, 2049) == -2047


def test_as5600_multi_turn_count_and_units():
    bus = FakeAS5600Bus()
    sensor = AS5600(bus)
    bus.raw = 4000
    sensor.start()
    angle = 4000
    for _ in range(3 * 40):  # three turns forward in 102-count steps, then back 1.5 turns
        angle = (angle + 102) % 4096
        bus.raw = angle
        assert sensor.sample()
    assert sensor.count == 3 * 40 * 102
    for _ in range(60):
        angle = (angle - 102) % 4096
        bus.raw = angle
        sensor.sample()
    assert sensor.count == 60 * 102
    assert sensor.usteps() == int(6120 * 12.5)
    assert abs(sensor.degrees() - 6120 * 360 / 4096) < 1e-9
    assert enc.counts_to_usteps(-3) == -37 and enc.counts_to_usteps(3) == 37  # truncation
    assert enc.counts_to_usteps(4096) == 51200


def test_as5600_failed_read_drops_the_sample():
    bus = FakeAS5600Bus()
    sensor = AS5600(bus)
    sensor.start()
    bus.raw = 50
    sensor.sample()
    bus.fail = True
    bus.raw = 90
    assert not sensor.sample()
    assert sensor.count == 50 and sensor.errors == 1
    bus.fail = False
    assert sensor.sample() and sensor.count == 90
    sensor.set_home()
    assert sensor.count == 0 and sensor.degrees() == 0.0


def test_as5600_samples_without_rewriting_its_pointer_until_another_register_is_read():
    bus = FakeAS5600Bus()
    sensor = AS5600(bus)
    bus.raw = 100
    sensor.start()
    writes = []
    set_pointer = bus.readfrom_mem_into
    bus.readfrom_mem_into = lambda addr, reg, buf: (writes.append(reg), set_pointer(addr, reg, buf))
    for raw in (110, 120):
        bus.raw = raw
        assert sensor.sample()
    assert writes == [] and sensor.count == 20
    assert sensor.status() == 0x20  # the pointer now lies past STATUS
    bus.raw = 130
    assert sensor.sample() and sensor.count == 30
    assert writes == [enc.STATUS, enc.RAW_ANGLE]
    bus.fail = True
    assert not sensor.sample()
    bus.fail = False
    bus.raw = 140
    assert sensor.sample() and sensor.count == 40 and writes[-1] == enc.RAW_ANGLE


def test_as5600_queued_reads_return_the_angle_of_the_previous_sample_with_its_tags():
    if MICROPYTHON:
        return  # the register fake is a Python object (see FakeI2CRegisters); the chip suite runs it
    bus = FakeAS5600Bus()
    regs = FakeI2CRegisters(bus)
    sensor = AS5600(bus, regs=regs)
    bus.raw = 100
    sensor.start()
    assert sensor.sample(7, 70) and sensor.count == 0  # blocking (nothing queued), then one queued
    assert (sensor.queued, regs.queued, list(sensor.s[enc.S_AT:enc.S_AT + 2])) == (1, 1, [7, 70])
    reads = bus.reads
    tags = [7, 70]
    for i, raw in enumerate((4090, 5, 20)):
        bus.raw = raw  # moves after the queued read: it shows at the sample after next
        assert sensor.sample(8 + i, 80 + i)
        assert list(sensor.s[enc.S_AT:enc.S_AT + 2]) == tags  # the read's own tags
        tags = [8 + i, 80 + i]
    assert sensor.count == -106 + 11 and sensor.raw == 5  # 100 -> 4090 -> 5: the short way round
    assert bus.reads == reads + 3 and regs.queued == 4  # no blocking read since


def test_as5600_queued_read_failures_drop_the_sample_and_fall_back_to_a_blocking_read():
    if MICROPYTHON:
        return  # see FakeI2CRegisters
    bus = FakeAS5600Bus()
    regs = FakeI2CRegisters(bus)
    sensor = AS5600(bus, regs=regs)
    bus.raw = 100
    sensor.start()
    sensor.sample()
    bus.fail = True
    sensor.sample()  # queued the read that NACKs
    assert not sensor.sample() and sensor.errors == 1 and not sensor.queued and not regs.aborted
    bus.fail = False
    bus.raw = 140
    assert sensor.sample() and sensor.count == 40 and sensor.queued  # blocking, then queued again
    regs.hold = True  # a read that never leaves the wire: given up after the spins, counted
    sensor.sample()
    assert not sensor.sample() and sensor.errors == 2 and not sensor.queued
    regs.hold = False
    regs.cmds = []
    bus.raw = 150
    assert sensor.sample() and sensor.count == 50
    assert sensor.status() == 0x20 and not sensor.queued  # machine.I2C waits for no queued read
    assert regs.rx == [] and regs.cmds == []
    bus.raw = 160
    assert sensor.sample() and sensor.count == 60  # pointer set again by a blocking read


def test_as5600_conf_register():
    assert enc.conf_word(3, 0) == 0x0300
    assert enc.conf_word(0, 1) == 0x0400
    assert enc.conf_word(2, 7) == 0x1E00
    bus = FakeAS5600Bus()
    AS5600(bus).configure(3, 1)
    assert bytes(bus.conf) == bytes([0x07, 0x00])


# ---- step generation ----

def test_usteps_per_pulse_and_period_math():
    assert [sg.usteps_per_pulse(m) for m in (256, 16, 1)] == [1, 16, 256]
    raises(ValueError, sg.usteps_per_pulse, 3)
    assert sg.period_cycles(900, 900) == 12  # 1 MHz: 12.5 MHz / 1 MHz
    assert sg.period_cycles(-900, 900) == 12  # direction does not matter
    assert sg.period_cycles(625, 10000) == 200  # 62 500 pulses/s (1e6 usteps/s at 16 microsteps)
    assert sg.period_cycles(9000, 900) == sg.MIN_PERIOD == 6
    assert sg.period_cycles(1, 10000) == sg.MAX_PERIOD == 0x3FFF + 5  # 100 pulses/s
    assert sg.period_cycles(0, 900) == sg.MAX_PERIOD


def test_burst_words():
    w = sg.burst_word(100, 125)
    assert w & 1 == 1 and (w >> 1) & 0x7FFF == 99 and w >> 16 == 120
    assert sg.burst_pulses(w) == 100 and sg.burst_cycles(w) == 5 + 100 * 125
    w = sg.burst_word(-1, 3)  # clamped up to the shortest legal period
    assert w & 1 == 0 and sg.burst_pulses(w) == -1 and w >> 16 == sg.MIN_DELAY
    w = sg.burst_word(sg.MAX_PULSES, 10 ** 6)
    assert sg.burst_pulses(w) == sg.MAX_PULSES and w >> 16 == sg.MAX_DELAY
    assert w < (1 << 30)  # stays a small int on 32-bit MicroPython


def test_plan_burst_truncates_and_clamps():
    pulses, word = sg.plan_burst(10, 1, 900, 1000)
    assert pulses == 10 and sg.burst_cycles(word) <= 0.0009 * sg.SM_FREQ + 5
    assert sg.plan_burst(-10, 1, 900, 1000)[0] == -10
    assert sg.plan_burst(47, 16, 900, 1000)[0] == 2  # whole 16-ustep pulses only, toward zero
    assert sg.plan_burst(-47, 16, 900, 1000)[0] == -2
    assert sg.plan_burst(0, 1, 900, 1000) == (0, 0)
    assert sg.plan_burst(5000, 1, 900, 1875)[0] == 1875
    assert sg.plan_burst(-5000, 1, 900, 1875)[0] == -1875
    assert sg.plan_burst(50, 1, 0, 0) == (0, 0)


class _Instr:
    def __init__(self, program, op, args):
        self.op = op
        self.args = args
        self.side_value = None  # optional side-set: the pin keeps its level
        self.delay = 0
        program.append(self)

    def side(self, value):
        self.side_value = value
        return self

    def __getitem__(self, delay):
        self.delay = delay
        return self


class FakeRP2:
    """Just enough of rp2.asm_pio to record the program for the emulator below."""

    class PIO:
        OUT_LOW = 0
        SHIFT_RIGHT = 1

    def __init__(self):
        self.options = None

    def asm_pio(self, **options):
        self.options = options

        def assemble(f):
            program = []
            labels = {}

            def instr(op):
                return lambda *args: _Instr(program, op, args)

            def label(name):
                labels[name] = len(program)

            names = {"label": label}
            for op in ("pull", "push", "mov", "out", "jmp"):
                names[op] = instr(op)
            for token in ("block", "noblock", "pins", "x", "y", "isr", "osr", "x_dec", "y_dec"):
                names[token] = token
            g = f.__globals__
            saved = {}
            for key in names:
                if key in g:
                    saved[key] = g[key]
                g[key] = names[key]
            try:
                f()
            finally:
                for key in names:
                    if key in saved:
                        g[key] = saved[key]
                    else:
                        del g[key]
            return program, labels

        return assemble


def run_pio(program, labels, words, max_cycles=10 ** 6):
    """Cycle-level emulation of the burst program until it stalls on an empty TX FIFO."""
    reg = {"x": 0, "y": 0, "isr": 0, "osr": 0}
    tx = list(words)
    rx = []
    step = direction = 0
    rises, falls = [], []
    pc = cycle = 0
    while cycle < max_cycles:
        ins = program[pc]
        if ins.op == "pull" and not tx:
            break
        assert not (ins.op == "push" and len(rx) >= 4)
        if ins.side_value is not None and ins.side_value != step:
            (rises if ins.side_value else falls).append((cycle, direction))
            step = ins.side_value
        nxt = pc + 1
        if ins.op == "pull":
            reg["osr"] = tx.pop(0)
        elif ins.op == "mov":
            reg[ins.args[0]] = reg[ins.args[1]]
        elif ins.op == "out":
            dest, bits = ins.args
            value = reg["osr"] & ((1 << bits) - 1)
            reg["osr"] >>= bits
            if dest == "pins":
                direction = value
            else:
                reg[dest] = value
        elif ins.op == "jmp":
            cond, target = ins.args
            counter = cond[0]
            if reg[counter]:
                nxt = labels[target]
            reg[counter] = (reg[counter] - 1) & 0xFFFFFFFF
        elif ins.op == "push":
            rx.append(reg["isr"])
            reg["isr"] = 0
        cycle += 1 + ins.delay
        pc = nxt % len(program)
    return rises, falls, rx, cycle


def test_pio_program_emits_the_burst_it_is_given():
    fake = FakeRP2()
    sys.modules["rp2"] = fake
    try:
        program, labels = sg.burst_program()
    finally:
        del sys.modules["rp2"]
    assert fake.options["out_shiftdir"] == FakeRP2.PIO.SHIFT_RIGHT
    assert len(program) <= 32
    words = [sg.burst_word(3, 100), sg.burst_word(-2, sg.MIN_PERIOD), sg.burst_word(1, 50)]
    rises, falls, rx, cycles = run_pio(program, labels, words)
    assert len(rises) == len(falls) == 6  # STEP ends low
    assert [d for _, d in rises] == [1, 1, 1, 0, 0, 1]
    assert rx == words  # each burst acknowledged with its own word, in order
    assert cycles == sum(sg.burst_cycles(w) for w in words)
    starts = [c for c, _ in rises]
    assert starts[1] - starts[0] == 100 and starts[2] - starts[1] == 100
    assert starts[4] - starts[3] == sg.MIN_PERIOD
    for (rise, _), (fall, _) in zip(rises, falls):
        assert fall - rise == sg.HIGH_CYCLES  # 240 ns at 12.5 MHz
    for i in range(1, len(rises)):
        assert rises[i][0] - falls[i - 1][0] >= 3  # low time >= 240 ns even at the fastest rate
    assert starts[3] - falls[2][0] >= 3  # DIR is set while STEP is low, before the next edge


def test_step_generator_counts_only_acknowledged_pulses():
    sm = FakeSM()
    gen = StepGenerator(sm, 256)
    assert gen.issue(100, 1000) == 100
    assert gen.position == 0 and gen.commanded == 100 and not gen.idle()
    gen.poll()
    assert gen.position == 0  # still in the PIO
    sm.finish()
    gen.poll()
    assert gen.position == 100 and gen.idle() and gen.field == 100
    assert gen.issue(100, 1000) == 0  # nothing more is owed
    assert gen.issue(40, 1000) == -60
    gen.shift(-500)
    assert gen.commanded == -460 and gen.position == -400 and gen.field == 100  # never relabelled
    for _ in range(10):  # the PIO stalls: at most MAX_IN_FLIGHT bursts are queued
        gen.issue(gen.commanded + 10, 1000)
    assert len(sm.tx) == sg.MAX_IN_FLIGHT
    coarse = StepGenerator(FakeSM(), 16)
    assert coarse.issue(40, 1000) == 2 and coarse.commanded == 32


def test_step_generator_limits_the_rate():
    gen = StepGenerator(FakeSM(), 256, max_rate=100000)
    assert gen.issue(10 ** 6, 1000) == 90  # 90 % of 1 ms at 100 kHz
    assert abs(gen.max_usteps_per_s() - 90000) < 1e-6
    fast = StepGenerator(FakeSM(), 256, max_rate=10 ** 7)
    assert fast.issue(10 ** 6, 1000) == int(0.0009 * sg.SM_FREQ) // sg.MIN_PERIOD


# ---- PicoStepper ----

def test_begin_configures_the_driver_and_encoder():
    b = Bench().begin()
    regs = b.uart.regs
    assert regs[tmc.GCONF] == 0x1C0
    assert regs[tmc.CHOPCONF] == 0x10000053  # MRES 0 = 256, vsense 0 for 1.5 A on 0.11 Ohm
    assert regs[tmc.IHOLD_IRUN] == tmc.ihold_irun(11, 11)  # 40 % of CS 26, as setup() does
    assert (regs[tmc.PWMCONF] >> 20) & 3 == tmc.FREEWHEEL_SHORT_LS
    assert regs[tmc.TPOWERDOWN] == 24 and regs[tmc.TPWMTHRS] == 6000
    assert b.uart.ifcnt == 7 and b.pin.level == 0
    assert bytes(b.i2c.conf) == bytes([0x03, 0x00])
    m = b.motor
    assert deg(m) == 0.0 and m.driver_position() == 0 and m.pid_error() == 0.0
    assert m.position_reached()


def test_begin_reports_hardware_faults():
    b = Bench()
    b.uart.drop_writes = True
    assert "IFCNT" in str(raises(TMCError, b.motor.begin))
    b = Bench()
    b.uart.regs[tmc.IOIN] = 0x20000000  # a TMC2208
    assert "0x20" in str(raises(TMCError, b.motor.begin))
    b = Bench()
    b.i2c.status = 0x00
    assert "magnet" in str(raises(OSError, b.motor.begin))
    b = Bench()
    b.uart.echo = False
    raises(TMCError, b.motor.begin)


def test_update_before_begin_touches_nothing():
    b = Bench()
    b.tick(5)
    assert b.uart.sent == [] and b.i2c.reads == 0 and b.sm.rx == []


def test_move_steps_lands_exactly_with_the_library_profile():
    b = Bench().begin()
    m = b.motor
    m.move_steps(51200)  # one revolution at 100 full steps/s, 2000 full steps/s^2
    ticks = b.run_until_reached()
    assert 2030 <= ticks <= 2080  # 2.05 s: 25 600 usteps/s cruise plus 50 ms ramps
    assert m.driver_position() == 51200
    assert abs(deg(m) - 360.0) < 0.1
    m.move_steps(-512)  # relative to the driver position
    b.run_until_reached()
    assert m.driver_position() == 50688


def test_move_angle_rounds_like_the_library():
    b = Bench().begin()
    b.motor.move_angle(to_q(-5.0, ANGLE_Q))  # -711.1 usteps -> -711
    b.run_until_reached()
    assert b.motor.driver_position() == -711
    b.motor.move_angle(to_q(0.0035, ANGLE_Q))  # 0.498 usteps -> 0
    b.tick()
    assert b.motor.position_reached()


def test_move_to_angle_is_absolute_in_the_encoder_frame():
    b = Bench().begin()
    m = b.motor
    b.rotor = -1280.0  # the rotor slipped 9 degrees back while the closed loop was off
    b.tick()
    m.move_to_angle(to_q(90.0, ANGLE_Q))
    b.run_until_reached()
    assert abs(deg(m) - 90.0) < 0.1  # the encoder reaches 90 degrees
    assert abs(m.driver_position() - (12800 + 1280)) < 13  # the driver frame carries the slip


def test_pid_error_sign_and_bounded_resync_on_a_blocked_rotor():
    b = Bench().begin()
    m = b.motor
    m.enable_closed_loop()
    m.set_control_threshold(15)
    m.set_max_acceleration(100000 * FS)
    m.set_rpm(10 * RPM)  # 8533 usteps/s: 8.5 usteps per 1 ms tick
    b.tick(300)
    free = 0.0
    for _ in range(50):
        b.tick()
        free = max(free, abs(m.pid_error()))
    assert free < 15  # quantisation only: below the threshold, no corrections
    b.blocked = True
    errors = []
    for _ in range(300):
        b.tick()
        errors.append(m.pid_error())
    assert min(errors[5:]) > 0  # the driver is ahead of the encoder in + direction
    assert max(errors) < 15 + 9 + 12.5  # bounded: re-sync whenever |e| >= threshold
    assert abs(m.driver_position() - deg(m) * 51200 / 360) < 15 + 9 + 12.5
    assert abs((m.encoder_rpm() / RPM)) < 1.0 and abs((m.driver_rpm() / RPM) - 10.0) < 1e-4
    m.set_rpm(-10 * RPM)
    b.blocked = False
    b.tick(400)
    b.blocked = True
    b.tick(50)
    assert m.pid_error() < 0  # moving in -: the sign follows the motion


def test_the_closed_loop_reads_the_state_words_where_encoder_and_ramp_keep_them():
    if MICROPYTHON:
        return  # const() names with a leading underscore are no module attributes there
    from joint.pico import motor
    from joint.motion import fixed, tickramp
    assert (motor._ES_COUNT, motor._ES_AT, motor._ES_NEXT, motor._RS_X, motor._RS_V, motor._LIMIT) == (
        enc.S_COUNT, enc.S_AT, enc.S_NEXT, tickramp.S_X, tickramp.S_V, fixed.LIMIT)
    assert (motor._RS_MODE, motor._RS_VMAX, motor._VELOCITY_POS, motor._VELOCITY_NEG) == (
        tickramp.S_MODE, tickramp.S_VMAX, tickramp.VELOCITY_POS, tickramp.VELOCITY_NEG)


def test_queued_encoder_reads_keep_the_pid_error_and_resync_of_blocking_reads():
    if MICROPYTHON:
        return  # see FakeI2CRegisters
    runs = []
    for queued in (False, True):
        b = Bench(queued=queued).begin()
        m = b.motor
        m.enable_closed_loop()
        m.set_control_threshold(15)
        m.set_rpm(30 * RPM)
        errors = []
        for i in range(600):
            b.blocked = 300 <= i < 400
            b.tick()
            errors.append(m.pid_error())
        runs.append((errors, m.driver_position(), deg(m), m.field_position()))
    (blocking, pos0, deg0, field0), (queued, pos1, deg1, field1) = runs
    assert max(abs(e) for e in queued[:300]) < 15  # moving freely: no lag shows as error
    assert max(queued[300:400]) < 15 + 26 + 12.5 and min(queued[310:400]) > 0
    assert abs(pos1 - pos0) <= 26 and abs(deg1 - deg0) < 0.2  # one tick of lag at most
    assert abs(field1 - field0) <= 26


def test_step_generator_on_the_pio_fifo_registers_moves_like_on_the_state_machine_methods():
    if MICROPYTHON:
        return  # see FakeI2CRegisters
    runs = []
    for pio in (False, True):
        b = Bench(pio=pio).begin()
        m = b.motor
        m.move_steps(20000)
        trace = []
        for _ in range(200):
            b.tick()
            trace.append((m.driver_position(), m.field_position(), b.emitted))
        m.set_rpm(-20 * RPM)
        b.tick(300)
        trace.append((m.driver_position(), m.field_position(), b.emitted, m.driver_rpm()))
        runs.append(trace)
        words = b.steps.pio.words if pio else 0
    assert runs[0] == runs[1] and runs[0][-1][2] != 0
    assert words > 400  # every burst went through the registers, out and back


def test_closed_loop_off_freezes_the_error_and_lets_it_grow():
    b = Bench().begin()
    m = b.motor
    m.set_rpm(10 * RPM)
    b.blocked = True
    b.tick(100)
    assert m.pid_error() == 0.0  # never ran: stays 0 (library quirk 1)
    m.enable_closed_loop()
    b.tick()
    first = m.pid_error()
    assert first > 500  # one large error after open-loop step loss, then a re-sync
    m.disable_closed_loop()
    b.tick(100)
    assert m.pid_error() == first
    assert m.driver_position() - b.rotor > 800  # the open-loop disagreement grows


def test_positioning_makes_up_slipped_steps():
    b = Bench().begin()
    m = b.motor
    m.enable_closed_loop()
    m.set_control_threshold(30)
    m.move_steps(12800)
    b.tick(200)
    b.rotor -= 512  # two full steps lost under load
    b.run_until_reached()
    assert abs(deg(m) - 90.0) < 0.2  # the target is met in the encoder frame
    assert abs(b.rotor - 12800) < 13 and m.driver_position() == 12800  # frames re-synchronised
    assert abs(b.emitted - (12800 + 512)) < 13  # the ramp added the lost steps


def test_set_home_zeroes_encoder_and_driver():
    b = Bench().begin()
    m = b.motor
    m.enable_closed_loop()
    m.set_control_threshold(30)
    m.move_steps(6400)
    b.run_until_reached()
    m.move_steps(1000)
    b.tick(30)  # part way
    remaining = 6400 + 1000 - m.driver_position()
    m.set_home()
    assert deg(m) == 0.0 and m.driver_position() == 0
    b.run_until_reached()
    assert abs(m.driver_position() - remaining) <= 1  # positioning keeps its remaining distance
    assert abs(deg(m) - remaining / 142.222) < 0.2
    assert abs(m.pid_error()) < 30  # no spurious correction move (library quirk 4 avoided)


def test_set_rpm_speed_estimator_and_stops():
    b = Bench().begin()
    m = b.motor
    m.set_rpm(60 * RPM)  # 51 200 usteps/s, ramping at the default 512 000 usteps/s^2
    b.tick(101)  # 0.1 s, plus a tick for the Q16 rounding of the acceleration
    assert abs((m.driver_rpm() / RPM) - 60.0) < 1e-4
    assert not m.position_reached()
    b.tick(900)
    assert abs((m.encoder_rpm() / RPM) - 60.0) < 0.6
    ticks = 0
    m.stop(True)  # about 2.98e6 usteps/s^2: 17 ms from 60 rpm
    while (m.driver_rpm() / RPM) != 0.0:
        b.tick()
        ticks += 1
    assert 16 <= ticks <= 19
    b.tick(2)
    assert m.position_reached()
    m.set_rpm(-30 * RPM)
    b.tick(300)
    ticks = 0
    m.stop(False)  # soft: the restored 512 000 usteps/s^2, 50 ms from 30 rpm
    b.tick()
    m.set_max_velocity(200 * FS)  # a new limit does not restart a stopping motor
    ticks = 1
    while (m.driver_rpm() / RPM) != 0.0:
        b.tick()
        ticks += 1
    assert 49 <= ticks <= 52
    b.tick(2)
    assert m.position_reached()
    held = m.driver_position()
    b.tick(50)
    assert m.driver_position() == held
    m.move_steps(51200)
    b.tick(500)
    assert abs((m.driver_rpm() / RPM) - 200 * 60 / 200) < 1e-4  # 200 full steps/s = 60 rpm


def test_coarse_microstepping_lands_within_one_pulse():
    b = Bench(microsteps=16).begin()
    m = b.motor
    assert b.uart.regs[tmc.CHOPCONF] >> 24 & 0xF == 4  # MRES for 16 microsteps
    m.move_steps(1000)  # not a multiple of 16 usteps
    b.run_until_reached()
    assert m.driver_position() == 992 and b.emitted == 992


def test_velocity_limits():
    b = Bench().begin()
    m = b.motor
    m.set_max_velocity(-10 ** 5 * FS)
    m.set_rpm(16000 * RPM)
    m.set_max_acceleration(10 ** 6 * FS)  # clamped to the TMC5130's 2.98e6 usteps/s^2
    b.tick(500)
    assert abs((m.driver_rpm() / RPM) * 51200 / 60 - 1080000) < 1e-3  # 90 % of the 1.2 MHz pulse rate


def test_currents_brake_and_direction_write_registers():
    b = Bench().begin()
    m = b.motor
    regs = b.uart.regs
    m.set_current(20)
    m.set_hold_current(0)
    assert regs[tmc.IHOLD_IRUN] == tmc.ihold_irun(0, 6)  # ceil(0.2 * 26)
    m.set_brake_mode(0)
    assert regs[tmc.IHOLD_IRUN] & 0x1F == 0 and (regs[tmc.PWMCONF] >> 20) & 3 == tmc.FREEWHEEL_OPEN
    m.set_brake_mode(1)
    assert (regs[tmc.PWMCONF] >> 20) & 3 == tmc.FREEWHEEL_SHORT_LS
    m.set_brake_mode(2)
    assert regs[tmc.IHOLD_IRUN] == tmc.ihold_irun(7, 6)  # 25 % of CS 26 -> 7
    assert (regs[tmc.PWMCONF] >> 20) & 3 == tmc.FREEWHEEL_NORMAL
    assert regs[tmc.PWMCONF] & ~(3 << 20) == 0xC10D0024 & ~(3 << 20)  # other fields untouched
    m.set_inverted(True)
    assert regs[tmc.GCONF] == 0x1C8
    m.set_inverted(False)
    assert regs[tmc.GCONF] == 0x1C0


def test_inverted_wiring_is_fixed_by_the_shaft_bit():
    b = Bench().begin()
    b.wiring = -1
    m = b.motor
    m.move_angle(to_q(10.0, ANGLE_Q))
    b.run_until_reached()
    assert deg(m) < 0
    m.set_inverted(True)
    m.move_angle(to_q(10.0, ANGLE_Q))
    b.run_until_reached()
    assert abs(deg(m)) < 0.1


def test_diagnostics_report_driver_and_magnet():
    b = Bench().begin()
    b.uart.regs[tmc.DRV_STATUS] = (1 << 31) | (20 << 16) | 1
    b.i2c.status = 0x30
    d = b.motor.diagnostics()
    assert d["stst"] and d["cs_actual"] == 20 and d["otpw"] and not d["ot"]
    assert d["magnet_detected"] and d["magnet_too_weak"] and not d["magnet_too_strong"]
    assert d["uart_faults"] == 0 and d["encoder_errors"] == 0


def test_uart_fault_after_begin_is_recorded_not_raised():
    b = Bench().begin()
    b.uart.echo = False
    b.motor.set_current(50)
    assert b.motor.faults == 1 and "echo" in b.motor.fault


def test_encoder_dropout_skips_the_closed_loop_tick():
    b = Bench().begin()
    m = b.motor
    m.enable_closed_loop()
    m.set_rpm(10 * RPM)
    b.tick(200)
    b.i2c.fail = True
    before = m.pid_error()
    b.tick(3)
    assert m.pid_error() == before
    b.i2c.fail = False
    b.tick(3)
    assert abs(m.pid_error()) < 30


def test_motor_config_validation_messages():
    assert validate_motor_config({"backend": "pico"}) == []
    assert validate_motor_config(dict(DEFAULTS)) == []
    assert validate_motor_config({"backend": "pico", "uart": 0, "uart_tx": 0, "uart_rx": 1,
                                  "encoder_i2c": 1, "encoder_sda": 2, "encoder_scl": 3}) == []
    problems = validate_motor_config({"uart_baud": 5, "microsteps": 12, "stepp": 3, "dir": "11",
                                      "uart_tx": 9, "encoder_sda": 7, "full_scale_ma": 1900,
                                      "enable": 10})
    text = "\n".join(problems)
    assert "uart_baud = 5 is out of range 9600..500000" in text
    assert "microsteps = 12 must be a power of two" in text
    assert "unknown key stepp" in text
    assert "dir must be an integer, got '11'" in text
    assert "uart_tx = 9 is not a TX pin of UART1 (use GP4, GP8, GP20, GP24)" in text
    assert "encoder_sda = 7 is not an SDA pin of I2C1" in text
    assert "full_scale_ma = 1900 cannot be set" in text
    assert "enable = 10 is already used by step" in text
    shared = validate_motor_config({"encoder_i2c": 0, "encoder_sda": 4, "encoder_scl": 5})
    assert any("joint bus" in p for p in shared)
    assert validate_motor_config({}, {"bus": 1, "sda": 2, "scl": 3}) != []
    assert validate_motor_config([]) == ["the motor config must be an object"]
