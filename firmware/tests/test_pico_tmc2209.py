"""The TMC2209 over its single-wire UART: datagrams, CRC, register fields, current scale.

Plain functions and bare asserts: this module runs under CPython (pytest) and the MicroPython unix
port (mprun.py); the fakes are pico_fakes.py's.
"""

from joint.pico import tmc2209 as tmc
from joint.pico import tmc2209_setup as tmc_setup
from joint.pico.tmc2209 import TMC2209, TMCError
from pico_fakes import FakeTMCBus, raises, ref_crc


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
