"""PicoStepper, the Pico's MotorHAL: the library's moves, the closed loop, currents, faults, its config checks.

Plain functions and bare asserts: this module runs under CPython (pytest) and the MicroPython unix
port (mprun.py); the fakes are pico_fakes.py's.
"""

from joint.pico import as5600 as enc
from joint.pico import tmc2209 as tmc
from joint.pico.motor_config import DEFAULTS, validate_motor_config
from joint.pico.tmc2209 import TMC2209, TMCError
from joint.motion.fixed import ANGLE_Q, RPM_Q, STEPS_Q, to_q
from joint.motion.hal import MAGNET_MISSING, MAGNET_OK, MAGNET_STRONG, MAGNET_WEAK
from joint.sim.clock import VirtualClock
from pico_fakes import Bench, FS, MICROPYTHON, RPM, deg, raises


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


class WrappingClock(VirtualClock):
    """The board's ticks_us: it wraps at 2**30, where a larger int would be a heap object."""

    PERIOD = 1 << 30

    def ticks_us(self):
        return self.now_us % self.PERIOD

    def ticks_diff(self, a, b):
        return (a - b + self.PERIOD // 2) % self.PERIOD - self.PERIOD // 2

    def ticks_add(self, a, delta):
        return (a + delta) % self.PERIOD


def test_the_period_grid_wraps_with_the_clock():
    """Across ticks_us's wrap (every 17.9 minutes on a Pico) a move lands as anywhere else, and
    the period grid stays a small int instead of growing past the wrap into a long int."""
    b = Bench(clock=WrappingClock(WrappingClock.PERIOD - 1000000)).begin()
    m = b.motor
    m.move_steps(51200)
    ticks = b.run_until_reached()
    assert 2030 <= ticks <= 2080 and m.driver_position() == 51200
    assert b.clock.now_us > WrappingClock.PERIOD
    assert 0 <= m._last_us < WrappingClock.PERIOD and m._last_us == b.clock.ticks_us()


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
    assert (motor._ES_RAW, motor._ES_COUNT, motor._ES_AT, motor._ES_NEXT, motor._RS_X, motor._RS_V, motor._LIMIT) == (
        enc.S_RAW, enc.S_COUNT, enc.S_AT, enc.S_NEXT, tickramp.S_X, tickramp.S_V, fixed.LIMIT)
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


def test_magnet_health_comes_from_the_as5600_status_bits():
    b = Bench().begin()
    for status, health in ((0x20, MAGNET_OK), (0x00, MAGNET_MISSING), (0x30, MAGNET_WEAK),
                           (0x28, MAGNET_STRONG), (0x10, MAGNET_MISSING)):
        b.i2c.status = status
        assert b.motor.magnet() == health, (status, b.motor.magnet())
    b.i2c.fail = True  # a sensor that does not answer cannot vouch for its magnet
    assert b.motor.magnet() == MAGNET_MISSING
    b.i2c.fail = False
    b.i2c.status = 0x20
    start = deg(b.motor)
    b.rotor += 1250  # 100 counts
    b.tick(5)  # sampling resumes after the status read moved the sensor's address pointer
    assert abs(deg(b.motor) - start - 8.789) < 0.01, deg(b.motor) - start


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
