"""The AS5600 encoder: angle, unwrap, multi-turn count, failed and queued reads.

Plain functions and bare asserts: this module runs under CPython (pytest) and the MicroPython unix
port (mprun.py); the fakes are pico_fakes.py's.
"""

from joint.pico import as5600 as enc
from joint.pico.as5600 import AS5600
from joint.motion.hal import MAGNET_MISSING, MAGNET_OK, MAGNET_STRONG, MAGNET_WEAK
from pico_fakes import FakeAS5600Bus, FakeI2CRegisters, MICROPYTHON


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
    assert [enc.magnet_health(s) for s in (0x20, 0x00, 0x30, 0x28, 0x18)] == [
        MAGNET_OK, MAGNET_MISSING, MAGNET_WEAK, MAGNET_STRONG, MAGNET_MISSING]


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
