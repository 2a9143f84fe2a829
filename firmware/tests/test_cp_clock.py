"""The CircuitPython joint's clock (cpy/clock.py): supervisor.ticks_ms's milliseconds, microseconds
as their count times 1000, every value and difference a small int on a 31-bit port, wrapping
together at 2**29 as MicroPython's ticks wrap at 2**30.

Plain functions and bare asserts: this module runs under CPython (pytest) and the MicroPython unix
port (mprun.py).
"""

from joint.cpy.clock import TICKS_PERIOD, TickClock

SMALL = 1 << 30  # CircuitPython's small ints on the RP2040: -2**30 .. 2**30 - 1


class FakeTicksMs:
    """supervisor.ticks_ms at a set count."""

    def __init__(self):
        self.ms = 0

    def __call__(self):
        return self.ms


def test_microseconds_are_the_milliseconds_times_1000_modulo_the_period():
    ticks = FakeTicksMs()
    clock = TickClock(ticks)
    for ms in (0, 1, 999, 0x3FFF, 0x4000, 1234567, TICKS_PERIOD // 1000, TICKS_PERIOD - 1):
        ticks.ms = ms
        us = clock.ticks_us()
        assert us == (ms * 1000) % TICKS_PERIOD and 0 <= us < SMALL, ms
        assert clock.ticks_ms() == ms


def test_a_millisecond_is_1000_microseconds_across_every_wrap():
    ticks = FakeTicksMs()
    clock = TickClock(ticks)
    for ms in (0, TICKS_PERIOD // 1000, TICKS_PERIOD - 3, 0x7FFFFF):
        ticks.ms = ms
        before_us, before_ms = clock.ticks_us(), clock.ticks_ms()
        ticks.ms = (ms + 5) % TICKS_PERIOD  # supervisor.ticks_ms wraps at 2**29
        assert clock.ticks_diff(clock.ticks_us(), before_us) == 5000
        assert clock.ticks_diff(clock.ticks_ms(), before_ms) == 5
        assert clock.ticks_diff(before_us, clock.ticks_us()) == -5000


def test_add_and_diff_wrap_within_the_period():
    clock = TickClock(FakeTicksMs())
    late = clock.ticks_add(TICKS_PERIOD - 10, 25)
    assert late == 15 and clock.ticks_diff(late, TICKS_PERIOD - 10) == 25
    assert clock.ticks_add(5, -10) == TICKS_PERIOD - 5
    half = TICKS_PERIOD // 2
    assert clock.ticks_diff(half - 1, 0) == half - 1 and clock.ticks_diff(half, 0) == -half
