"""Encoder calibration on the joint: the table in its configuration is checked (a bad one is an
error and unused), the HAL subtracts it wherever the encoder is read, and each simulated encoder
has an error of its own that only a calibration tells the firmware.

Plain functions and bare asserts: runs under CPython (pytest) and the MicroPython unix port.
"""

from joint.config import schema as config
from joint.core.controller_init import encoder_table
from joint.sim import mechanics
from joint.sim.clock import VirtualClock
from joint.sim.stepper import SimStepper
from test_s32_backend import S32Joint, begun, check_the_main_loop_allocates_nothing, motor_on
from s32_fakes import Board
from pico_fakes import Bench


def _with_encoder(encoder, backend="sim"):
    return config.parse({"joint": "J1", "address": 0x11, "motor": {"backend": backend}, "encoder": encoder},
                        "j.json")


def test_a_calibration_table_is_loaded_from_the_configuration():
    table = [(i * 37) % 101 - 50 for i in range(32)]
    cfg = _with_encoder({"correction": table})
    assert cfg.valid, cfg.errors
    assert list(cfg.encoder.correction) == table
    assert config.parse({"joint": "J1", "address": 0x11}).encoder.correction == (), "none by default"


def test_a_malformed_or_hostile_table_is_an_error_and_is_not_used():
    cases = (
        ({"correction": [0] * 31}, "encoder.correction must be a list of 16, 32 or 64 integers (motor millidegrees), got 31"),
        ({"correction": [0] * 100000}, "got 100000"),
        ({"correction": "0,0,0"}, "got '0,0,0'"),
        ({"correction": {"a": 1}}, "must be a list of 16, 32 or 64 integers"),
        ({"correction": [0] * 31 + [0.5]}, "encoder.correction must be an integer, got 0.5"),
        ({"correction": [0] * 31 + [True]}, "encoder.correction must be an integer, got True"),
        ({"correction": [0] * 31 + [[1]]}, "encoder.correction must be an integer, got [1]"),
        ({"correction": [0] * 31 + [5001]}, "encoder.correction = 5001 is out of range -5000..5000"),
        ({"correction": [0] * 32, "gain": 2}, "unknown key encoder.gain"),
        (7, "encoder must be an object"),
    )
    for encoder, message in cases:
        cfg = _with_encoder(encoder)
        assert not cfg.valid and cfg.encoder.correction == (), encoder
        assert any(message in e for e in cfg.errors), (message, cfg.errors)


def _stepper(joint, seed):
    clock = VirtualClock()
    return clock, SimStepper(clock, seed=seed, **mechanics.stepper_kwargs(joint))


def _profile(stepper, points=72):
    return [stepper.encoder_error(i * 360.0 / points) for i in range(points)]


def _peak(profile):
    mean = sum(profile) / len(profile)
    return max(abs(e - mean) for e in profile)


def test_each_simulated_encoder_has_its_own_error_within_the_datasheet():
    bound = sum(mechanics.ENCODERS["tle5012b"]["harmonics"]["nominal"])
    profiles = [_profile(_stepper(joint, seed)[1]) for joint, seed in (("J1", 1), ("J1", 2), ("J1", 3), ("J3", 1))]
    peaks = [_peak(p) for p in profiles]
    assert all(0.2 < peak <= bound + 0.02 for peak in peaks), peaks  # + a count's floor
    for i in range(len(profiles)):
        for j in range(i + 1, len(profiles)):
            assert max(abs(a - b) for a, b in zip(profiles[i], profiles[j])) > 0.1, (i, j)


def test_the_simulated_hal_subtracts_the_table_from_what_the_firmware_reads():
    for seed in (1, 2, 3):
        clock, stepper = _stepper("J1", seed)
        raw = _peak(_profile(stepper, 720))
        # What the encoder misreads over a turn of the sensor, found from the sensor's own angle.
        home = stepper.encoder_zero()
        table = [int(round(1000.0 * stepper.encoder_error(i * 360.0 / 32 - home))) for i in range(32)]
        stepper.set_encoder_correction(encoder_table(table, stepper._encoder_cpr))
        calibrated = _peak(_profile(stepper, 720))
        assert calibrated < 0.1 * raw, (seed, raw, calibrated)
        # The readings the firmware takes (angle_moved, the closed loop) are corrected too.
        stepper.begin()
        stepper.enable_closed_loop()
        rotor0, worst = stepper.rotor_angle(), 0.0
        for _ in range(12):
            stepper.move_angle(30.0)
            for _ in range(300):
                clock.advance(1000)
                stepper.update()
            worst = max(worst, abs(stepper.angle_moved() - (stepper.rotor_angle() - rotor0)))
        assert worst < 0.25 * raw, (seed, raw, worst)


def _misreading_board(amplitude):
    """A TLE5012B whose angle is off by a triangle wave of `amplitude` counts over its turn."""
    board = Board()
    tle = board.tle
    true_raw = tle.raw

    def error(angle):
        return abs((angle * 4 * amplitude) // 32768 - 2 * amplitude) - amplitude

    def raw():
        angle = true_raw()
        return (angle + error(angle)) & 0x7FFF
    tle.raw = raw
    return board, error


def _worst_misreading(board, motor):
    worst = 0
    start = board.rotor.position
    for step in range(1, 33):
        board.rotor.position = start + step * 1600
        motor.update()
        moved = (board.rotor.position - start) * 16 // 25  # counts
        worst = max(worst, abs(motor.angle_moved() // 45 - moved))
    return worst


def test_the_s32_backend_subtracts_the_table_from_every_reading():
    amplitude = 100
    board, error = _misreading_board(amplitude)
    raw_board, _ = _misreading_board(amplitude)
    # The table in motor millidegrees at 16 angles of the sensor, as `bioscara calibrate` stores it.
    table = [int(round(error(i * 2048) * 360000 / 32768)) for i in range(16)]
    motor = motor_on(board)
    motor.set_encoder_correction(encoder_table(table, 32768))
    motor.begin()
    _, raw_motor = begun(raw_board)
    assert _worst_misreading(raw_board, raw_motor) > amplitude
    assert _worst_misreading(board, motor) <= 3


def test_a_calibrated_s32_joint_reports_its_encoder_zero_and_its_main_loop_allocates_nothing():
    table = [int(round(900 * ((i * 7) % 16 - 7.5) / 7.5)) for i in range(16)]
    j = S32Joint(cfg=config.parse({"joint": "J1", "address": 0x11, "motor": {"backend": "s32"},
                                   "i2c": {"bus": 1}, "encoder": {"correction": table}}, "j.json"))
    assert j.motor._encoder_table is not None, "the boot loaded the table"
    # The sensor's angle where ANGLEMOVED reads 0 (the fake's magnet sits at 12345 counts at rotor 0;
    # the boot's orientation check ends where it began), calibration applied.
    zero = j.read("ENCODERZERO")[0][0]
    assert abs(zero - j.motor._corrected(j.board.tle.raw()) * 360.0 / 32768) < 0.05, zero
    check_the_main_loop_allocates_nothing(j)


def _misreading_bench(amplitude):
    """A PicoStepper bench whose AS5600 reads off by a triangle wave of `amplitude` counts a turn."""
    bench = Bench()

    def error(angle):
        return abs((angle * 4 * amplitude) // 4096 - 2 * amplitude) - amplitude

    def encode():
        true = (int(bench.rotor // 12.5) + bench.offset) % 4096
        bench.i2c.raw = (true + error(true)) % 4096
    bench._encode = encode
    encode()
    return bench, error


def _pico_worst_misreading(bench):
    worst = 0
    start = bench.rotor
    bench.tick(2)
    begin = bench.motor.angle_moved()
    for step in range(1, 65):
        bench.rotor = start + step * 800
        bench.tick(2)
        moved = int((bench.rotor - start) // 12.5)  # counts
        worst = max(worst, abs((bench.motor.angle_moved() - begin) // 360 - moved))
    return worst


def test_the_pico_backend_subtracts_the_table_from_every_reading():
    amplitude = 12  # counts of the AS5600's 4096: about 1 degree
    raw_bench, _ = _misreading_bench(amplitude)
    bench, error = _misreading_bench(amplitude)
    table = [int(round(error(i * 128) * 360000 / 4096)) for i in range(32)]
    bench.motor.set_encoder_correction(encoder_table(table, 4096))
    raw_bench.begin()
    bench.begin()
    assert _pico_worst_misreading(raw_bench) > amplitude
    assert _pico_worst_misreading(bench) <= 2
    # Where ANGLEMOVED is 0, in the sensor's own (corrected) angle: the magnet's 1000 counts at rotor 0.
    bench.motor.set_home()
    bench.tick(2)
    expected = (int(bench.rotor // 12.5) + bench.offset) % 4096
    assert abs(bench.motor.encoder_zero() // 360 - expected) <= 2, (bench.motor.encoder_zero() // 360, expected)
