"""uStepper S32 backend (TMC5130 + TLE5012B) against register-level fakes that follow the datasheets.

Plain functions and bare asserts: this module runs under CPython (pytest) and the MicroPython unix
port (mprun.py). The fakes (s32_fakes.py) speak the chips' SPI frames; the joint tests run the
real core on them through the legacy protocol, as a host would.
"""

import gc
import sys

from joint.config import schema as config
from joint.spec import protocol as P
from joint.core.controller import JointController
from joint.motion.fixed import ANGLE_Q, RPM_Q, STEPS_Q
from joint.motion.hal import MAGNET_MISSING, MAGNET_OK
from joint.links.i2c_target import I2CTargetAdapter
from joint.console.log import Logger
from joint.s32 import board as s32_board
from joint.s32 import v2 as s32_v2
from joint.spec import protocol_v2 as V
from joint.s32 import tmc5130 as tmc
from joint.s32.motor import S32Stepper
from joint.s32.tle5012b import TLE5012B, crc8, crc_table
from joint.s32.tmc5130 import TMC5130, TMCError
from joint.sim.clock import VirtualClock
from joint.sim.i2c_target import FakeI2CTarget
from pico_fakes import raises
from s32_fakes import Board
from v2rig import V2Rig

MICROPYTHON = sys.implementation.name == "micropython"
FS = 1 << STEPS_Q
RPM = 1 << RPM_Q
BUSY, STALL, NOTHOMED = P.FLAG_BUSY, P.FLAG_STALL, P.FLAG_NOTHOMED


class SPI:
    """machine.SPI in front of a fake chip (its methods, by name)."""

    def __init__(self, chip):
        self._chip = chip

    def write_readinto(self, tx, rx):
        self._chip.write_readinto(tx, rx)

    def write(self, buf):
        self._chip.write(buf)

    def readinto(self, buf, fill=0):
        self._chip.readinto(buf, fill)


def motor_on(board):
    return S32Stepper(TMC5130(SPI(board.tmc), board.tmc.cs), TLE5012B(SPI(board.tle), board.tle.cs, board.tle.release))


def begun(board=None):
    board = board or Board()
    motor = motor_on(board)
    motor.begin()
    return board, motor


def run(board, motor, ms):
    for _ in range(ms):
        board.tick_ms()
        motor.update()


# ---- TMC5130 frames and units ----

def test_a_write_is_one_datagram_with_the_write_bit_msb_first():
    sent = []

    class Capture:
        def write_readinto(self, tx, rx):
            sent.append(bytes(tx))

    pins = []
    drv = TMC5130(Capture(), pins.append)
    drv.write(tmc.XTARGET, -2)
    assert sent == [bytes([0xAD, 0xFF, 0xFF, 0xFF, 0xFE])]
    assert pins == [1, 0, 1], "chip select idles high and frames the datagram"


def test_a_read_takes_two_datagrams_and_returns_the_second_reply():
    board = Board()
    board.tmc.regs[tmc.XACTUAL] = -123456
    drv = TMC5130(SPI(board.tmc), board.tmc.cs)
    before = board.tmc.frames
    assert drv.read(tmc.XACTUAL) == -123456
    assert board.tmc.frames - before == 2
    board.tmc.v = -5000
    drv.frame(tmc.XACTUAL, 0)
    assert drv.frame(tmc.VACTUAL, 0) == -123456, "each frame returns the previous request's register"
    assert drv.frame(tmc.VACTUAL, 0) == (-5000) & 0xFFFFFF
    assert tmc.signed24((-5000) & 0xFFFFFF) == -5000


def test_a_missing_driver_is_reported():
    board = Board(present=False)
    exc = raises(TMCError, motor_on(board).begin)
    assert "no TMC5130" in str(exc)


def test_units_follow_the_datasheet_at_10_mhz():
    # ustepper-model.md section 2: VMAX = v[usteps/s] / 0.596046, AMAX = a[usteps/s^2] / 45.4747
    assert abs(tmc.vmax_of_fs_q4(100 * FS) - 100 * 256 / 0.596046) < 2
    assert abs(tmc.amax_of_fs_q4(2000 * FS) - 2000 * 256 / 45.4747) < 2
    assert tmc.amax_of_fs_q4(20000 * FS) == tmc.AMAX_LIMIT, "the library clamps AMAX at 0xFFFE"
    assert tmc.vmax_of_fs_q4(320000) == tmc.VMAX_LIMIT
    # setRPM(100) writes VMAX = int(100 * 1431.6557) = 143165 (section 8.8)
    assert abs(tmc.vmax_of_rpm_q16(100 * RPM) - 143165) <= 1
    assert tmc.vmax_of_rpm_q16(-100 * RPM) == tmc.vmax_of_rpm_q16(100 * RPM)
    assert abs(tmc.rpm_q16_of_vactual(143165) - 100 * RPM) < RPM // 100
    assert tmc.percent_to_cs(100) == 31 and tmc.percent_to_cs(50) == 15 and tmc.percent_to_cs(0) == 0


# ---- TLE5012B SSC ----

def _bitwise_crc(data):
    crc = 0xFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1D) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc ^ 0xFF


def test_the_crc_is_the_datasheets_crc8_0x1d():
    table = crc_table()
    for frame in (b"\x80\x21\x80\x00", b"\x80\x21\xff\xff", b"\x00\x00\x00\x00", b"\x80\x21\x9a\x5c"):
        assert crc8(table, frame, 4) == _bitwise_crc(frame)


def test_an_angle_read_releases_mosi_while_the_sensor_answers():
    board = Board()
    enc = TLE5012B(SPI(board.tle), board.tle.cs, board.tle.release)
    board.rotor.position = 51200 // 4  # a quarter turn
    assert enc.read_angle() == (8192 + board.tle.offset) & 0x7FFF
    assert board.tle.contention == 0 and not board.tle.released and not board.tle.selected


def test_a_bad_safety_word_or_crc_is_not_an_angle():
    board = Board()
    enc = TLE5012B(SPI(board.tle), board.tle.cs, board.tle.release)
    for fault in (0x4000, 0x2000, 0x1000):
        board.tle.fault = fault
        assert enc.read_angle() == -1
    board.tle.fault = 0
    board.tle.corrupt_crc = True
    assert enc.read_angle() == -1
    assert enc.errors == 4
    board.tle.corrupt_crc = False
    assert enc.read_angle() >= 0


# ---- the backend ----

def test_begin_configures_the_driver_as_the_library_does():
    board, motor = begun()
    r = board.tmc.regs
    assert r[tmc.GCONF] == 0x05, "AIN current reference, StealthChop"
    assert r[tmc.CHOPCONF] & 0x0F000000 == 0, "MRES 0: 256 microsteps"
    assert r[tmc.CHOPCONF] == 0x00010042
    assert r[tmc.RAMPMODE] == tmc.POSITIONING and r[tmc.XACTUAL] == 0 and r[tmc.XTARGET] == 0
    assert r[tmc.VSTOP] >= 10 and r[tmc.D1] != 0, "the datasheet forbids 0 in positioning mode"
    assert r[tmc.IHOLD_IRUN] & 0x1F == 12 and (r[tmc.IHOLD_IRUN] >> 8) & 0x1F == 12
    assert motor.angle_moved() == 0


def test_a_broken_encoder_fails_begin():
    board = Board()
    board.tle.fault = 0x1000
    raises(OSError, motor_on(board).begin)


def test_the_magnet_is_missing_when_the_safety_word_flags_the_angle():
    board, motor = begun()
    assert motor.magnet() == MAGNET_OK
    for fault in (0x4000, 0x2000, 0x1000):
        board.tle.fault = fault
        assert motor.magnet() == MAGNET_MISSING
    board.tle.fault = 0
    board.tle.corrupt_crc = True
    assert motor.magnet() == MAGNET_MISSING
    board.tle.corrupt_crc = False
    assert motor.magnet() == MAGNET_OK


def test_move_to_angle_writes_xtarget_in_usteps_and_arrives():
    board, motor = begun()
    motor.set_max_velocity(200 * FS)
    motor.set_max_acceleration(2000 * FS)
    motor.set_max_deceleration(2000 * FS)
    motor.move_to_angle(90 << ANGLE_Q)
    assert board.tmc.regs[tmc.XTARGET] == 12800, "90 degrees = 51200 / 4 usteps"
    assert board.tmc.regs[tmc.VMAX] == tmc.vmax_of_fs_q4(200 * FS)
    assert not motor.position_reached()
    run(board, motor, 1500)
    assert motor.position_reached()
    assert abs(motor.angle_moved() / (1 << ANGLE_Q) - 90.0) < 0.02
    motor.move_angle(-45 << ANGLE_Q)
    assert board.tmc.regs[tmc.XTARGET] == 12800 - 6400


def test_set_rpm_runs_the_velocity_ramp_and_the_estimator_follows():
    board, motor = begun()
    motor.set_max_acceleration(2000 * FS)
    motor.set_rpm(-30 * RPM)
    assert board.tmc.regs[tmc.RAMPMODE] == tmc.VELOCITY_NEG
    run(board, motor, 1000)
    assert abs(motor.driver_rpm() + 30 * RPM) < RPM // 10
    assert abs(motor.encoder_rpm() + 30 * RPM) < RPM, motor.encoder_rpm() / RPM
    assert motor.angle_moved() < 0


def test_stop_ramps_down_then_holds_in_positioning_mode():
    board, motor = begun()
    motor.set_max_acceleration(500 * FS)
    motor.set_rpm(60 * RPM)
    run(board, motor, 500)
    motor.stop(hard=True)
    assert board.tmc.regs[tmc.AMAX] == tmc.AMAX_LIMIT and board.tmc.regs[tmc.VMAX] == 0
    run(board, motor, 200)
    r = board.tmc.regs
    assert r[tmc.RAMPMODE] == tmc.POSITIONING and r[tmc.XTARGET] == r[tmc.XACTUAL]
    assert r[tmc.AMAX] == tmc.amax_of_fs_q4(500 * FS), "the stored acceleration is back"
    held = motor.angle_moved()
    run(board, motor, 100)
    assert motor.angle_moved() == held


def test_the_closed_loop_relabels_xactual_to_the_encoder():
    board, motor = begun()
    motor.set_control_threshold(15)
    motor.enable_closed_loop()
    motor.set_max_acceleration(2000 * FS)
    motor.set_rpm(10 * RPM)
    board.rotor.wall = 200  # usteps: blocked almost at once
    run(board, motor, 400)
    r = board.tmc.regs
    measured = (motor.angle_moved() // 45 * 25) >> 4
    assert abs(r[tmc.XACTUAL] - measured) < 40, "XACTUAL follows the encoder, not the field"
    assert board.tmc.field - r[tmc.XACTUAL] > 1000, "the field ran on"
    assert motor.field_position() == board.tmc.field & 0x3FFFFFFF
    assert 0 < motor.pid_error() < 200


def test_without_the_closed_loop_the_error_freezes():
    board, motor = begun()
    motor.set_rpm(10 * RPM)
    board.rotor.wall = 200
    run(board, motor, 300)
    assert motor.pid_error() == 0 and board.tmc.regs[tmc.XACTUAL] == board.tmc.field


def test_set_home_zeroes_encoder_and_driver_keeping_a_moves_distance():
    board, motor = begun()
    motor.set_max_velocity(100 * FS)
    motor.set_max_acceleration(2000 * FS)
    motor.move_steps(5000)
    run(board, motor, 20)
    x = board.tmc.regs[tmc.XACTUAL]
    motor.set_home()
    r = board.tmc.regs
    assert r[tmc.XACTUAL] == 0 and r[tmc.XTARGET] == 5000 - x
    assert motor.angle_moved() == 0
    field = motor.field_position()
    run(board, motor, 3)
    assert motor.field_position() - field >= 0, "the field position continues across set_home"


def test_currents_brake_and_direction_registers():
    board, motor = begun()
    motor.set_current(50)
    motor.set_hold_current(20)
    r = board.tmc.regs
    assert (r[tmc.IHOLD_IRUN] >> 8) & 31 == 15 and r[tmc.IHOLD_IRUN] & 31 == 6
    motor.set_brake_mode(1)
    assert (r[tmc.PWMCONF] >> 20) & 3 == 2 and r[tmc.IHOLD_IRUN] & 31 == 0, "coils shorted"
    motor.set_brake_mode(0)
    assert (r[tmc.PWMCONF] >> 20) & 3 == 1
    motor.set_brake_mode(2)
    assert r[tmc.IHOLD_IRUN] & 31 == 7
    motor.set_inverted(True)
    assert r[tmc.GCONF] & tmc.SHAFT
    motor.set_inverted(False)
    assert not r[tmc.GCONF] & tmc.SHAFT


def test_the_configuration_is_read_from_flash_up_to_erased_bytes():
    flash = bytearray(b"\xff" * 128)
    text = b'{"joint": "J2", "address": 18, "i2c": {"bus": 1}, "motor": {"backend": "s32"}}'
    flash[0:len(text)] = text
    assert s32_board.read_config(flash, 0, 128) == text
    cfg = config.parse_bytes(s32_board.read_config(flash, 0, 128), s32_board.CONFIG_SOURCE)
    assert cfg.valid and cfg.joint == "J2" and cfg.motor == {"backend": "s32"}, cfg.errors
    bad = config.parse_bytes(b'{"joint": "J2", "address": 18, "motor": {"backend": "s32"}}', "flash")
    assert not bad.valid and "I2C1" in bad.errors[0]
    assert not config.parse_bytes(b"\x00", "flash").valid


# ---- the joint on the S32 backend, driven through the legacy protocol ----

class S32Joint:
    """JointController + I2CTargetAdapter + S32Stepper on the fakes, booted."""

    def __init__(self, joint="J1", cfg=None):
        self.clock = VirtualClock()
        self.board = Board()
        self.motor = motor_on(self.board)
        self.cfg = cfg or config.default(joint)
        self.lines = []
        self.core = JointController(self.motor, self.clock, self.cfg, Logger(joint, write=self.lines.append))
        self.target = FakeI2CTarget(self.cfg.address)
        self.adapter = I2CTargetAdapter(self.core)
        self.adapter.attach(self.target)
        self.tick(30000, until=lambda: self.core.ready)
        assert self.core.ready and not self.core.disabled, self.lines

    def tick(self, n=1, until=None, poll_every=10):
        for i in range(n):
            self.clock.advance(1000)
            self.board.tick_ms()
            if poll_every and i % poll_every == 0:
                self.read("ANGLEMOVED")  # a host's cycle feeds the deadman
            self.core.service()
            if until is not None and until():
                return True
        return False

    def command(self, name, *values):
        reg = P.register(name)
        return self.target.transfer(bytes([reg.addr]) + reg.encode(*values), 1)[0]

    def read(self, name):
        reg = P.register(name)
        reply = self.target.transfer(bytes([reg.addr]), reg.rsize + 1)
        return reg.decode(reply[:-1]), reply[-1]

    def flags(self):
        return self.read("PING")[1]

    def bytes_per_service(self, n):
        """Heap bytes allocated per service() (None under CPython, which boxes every int)."""
        if not MICROPYTHON:
            self.tick(n)
            return None
        total = 0
        for i in range(n):
            self.clock.advance(1000)
            self.board.tick_ms()
            if i % 10 == 0:
                self.read("ANGLEMOVED")
            gc.collect()
            before = gc.mem_alloc()
            self.core.service()
            total += gc.mem_alloc() - before
        return total / n


def test_moving_to_an_angle_reaches_xtarget_in_the_right_units():
    j = S32Joint()
    assert j.command("SETUP", 40, 20, 0, 0) & P.FLAG_NOTENABLED == 0
    j.command("SETMAXVELOCITY", 90.0)
    j.command("MOVETOANGLE", 45.0)
    j.tick(2)
    r = j.board.tmc.regs
    assert abs(r[tmc.XTARGET] - 6400) <= 16, r[tmc.XTARGET]
    j.tick(3000)
    assert abs(j.read("ANGLEMOVED")[0][0] - 45.0) < 0.1


def test_home_ends_at_the_wall():
    j = S32Joint()
    j.command("SETUP", 20, 20, 0, 0)
    j.command("SETMAXACCELERATION", 360.0)
    j.tick(2)
    j.board.rotor.wall = 40 * 51200 // 360  # 40 motor degrees away
    assert j.command("HOME", 1, 10, 30, 15) & (BUSY | NOTHOMED) == BUSY | NOTHOMED
    done = j.tick(20000, until=lambda: not j.flags() & BUSY)
    assert done and not j.flags() & NOTHOMED, j.lines
    j.tick(300)
    assert abs(j.read("ANGLEMOVED")[0][0]) < 5.0, "encoder zeroed at the wall"
    assert abs(j.board.rotor.position - j.board.rotor.wall) <= 1024, "within a pole pitch of the wall"


def test_the_deadman_stops_a_joint_its_host_forgot():
    j = S32Joint()
    j.command("SETUP", 20, 20, 0, 0)
    j.command("SETRPM", 30.0)
    j.tick(500)
    assert j.board.tmc.v != 0
    j.tick(1000, poll_every=0)  # the host stops polling
    assert j.board.tmc.v == 0 and j.board.tmc.regs[tmc.RAMPMODE] == tmc.POSITIONING


def test_a_blocked_joint_stalls():
    j = S32Joint()
    j.command("SETUP", 20, 20, 0, 0)
    j.command("ENABLESTALLGUARD", 2)
    j.command("SETMAXACCELERATION", 3600.0)
    j.command("SETRPM", 60.0)
    j.tick(500)
    assert abs(j.read("GETDRIVERRPM")[0][0] - 60.0) < 1.0
    j.board.rotor.wall = j.board.rotor.position + 100
    assert j.tick(3000, until=lambda: j.flags() & STALL)
    j.tick(300)
    assert j.board.tmc.v == 0


def test_the_main_loop_allocates_nothing_on_the_s32_backend():
    check_the_main_loop_allocates_nothing(S32Joint())


def check_the_main_loop_allocates_nothing(j):
    """Enable `j`, then turn, position and stop it: no heap bytes per service() (MicroPython)."""
    j.command("SETUP", 40, 20, 0, 0)
    for name, values in (("SETRPM", (60.0,)), ("MOVETOANGLE", (90.0,)), ("STOP", (0,))):
        j.command(name, *values)
        j.tick(5)
        got = j.bytes_per_service(300)
        assert got is None or got == 0, "%s: %s bytes per service()" % (name, got)


def test_v2_waits_for_a_read_from_this_joint_only():
    sr2 = 0x40005418  # I2C1's SR2 (RM0368 18.6.7); I2C2's 0x400 above it
    mem32 = {sr2: 0, sr2 + 0x400: 0}
    reading = s32_v2.read_in_progress(mem32, 1)
    assert not reading()
    mem32[sr2] = 0x2  # BUSY alone: another joint's transaction, or this joint's write phase
    assert not reading()
    mem32[sr2 + 0x400] = 0x6  # a read on I2C2
    assert not reading()
    mem32[sr2] = 0x6  # BUSY and TRA: the host reads this joint's state block
    assert reading()


def _v2_on_the_s32(read_us, step_us=100):
    """A joint serving v2 through S32MemLink, whose next swap meets a read that lasts `read_us`
    of its clock (each look at TRA takes `step_us`)."""
    rig = V2Rig(port="stm32", mem_link=s32_v2.S32MemLink)
    rig.to_v2()
    left = [read_us]

    def reading():
        rig.clock.advance(step_us)
        left[0] -= step_us
        return left[0] >= 0
    rig.link.attach(rig.switch.target, reading)
    return rig


def test_v2_on_the_s32_waits_a_read_out_and_publishes_the_ack_in_the_same_pass():
    rig = _v2_on_the_s32(read_us=300)
    rig.exchange(rig.frame())
    assert rig.link.deferred == 0 and rig.link.ack == rig.seq
    assert V.decode_state(rig.address, rig.xfer(rig.frame(), V.STATE_SIZE))[4] == rig.seq - 1


def test_v2_on_the_s32_defers_the_swap_when_a_read_never_ends():
    rig = _v2_on_the_s32(read_us=1 << 20)
    before = bytes(rig.link.mem)
    rig.exchange(rig.frame())
    assert rig.link.deferred == 1 and rig.link.ack != rig.seq
    assert bytes(rig.link.mem[V.STATE:]) == before[V.STATE:]


def test_v2_on_the_s32_allocates_nothing():
    rig = V2Rig(port="stm32", mem_link=s32_v2.S32MemLink)
    rig.to_v2()
    target = rig.switch.target
    rig.link.attach(target, s32_v2.read_in_progress({0x40005418: 0}, 1))  # I2C1's SR2: no read
    for raw in (rig.frame(), rig.frame()):
        target.transfer(raw, V.STATE_SIZE)
        rig.service_heap_locked()
    assert rig.link.ack == rig.seq and rig.link.deferred == 0
