"""The core's clock on CircuitPython (core.clock.MonotonicClock's interface) in small ints.

CircuitPython has no time.ticks_*; the CPython stand-in's `time.monotonic_ns() // 1000` makes a
long int a call (67 us and 32 bytes on the chip), and the loop asks for the time several times
an iteration. `supervisor.ticks_ms()` is a small int that wraps at 2**29: milliseconds come from
it and microseconds are its count times 1000, so they advance in whole milliseconds, which is the
loop's own tick (the motor's period grid and the deadman need no finer). Both wrap at TICKS_PERIOD
like MicroPython's ticks, so ticks_diff and ticks_add serve both.
"""

from ..micro import const

TICKS_PERIOD = const(0x20000000)  # supervisor.ticks_ms wraps at 2**29
_TICKS_MASK = const(0x1FFFFFFF)
_TICKS_HALF = const(0x10000000)
_LOW_MASK = const(0x3FFF)  # ticks_us: the milliseconds in two parts, each product a small int
_HIGH_MASK = const(0x7FFF)


class TickClock:
    def __init__(self, ticks_ms):
        self.ticks_ms = ticks_ms  # supervisor.ticks_ms: a builtin, called without binding

    def ticks_us(self):
        """(ticks_ms() * 1000) mod 2**29: the low 14 bits times 1000 plus the high bits' product
        mod 2**15 shifted by 14, never beyond a small int."""
        ms = self.ticks_ms()
        return ((ms & _LOW_MASK) * 1000 + ((((ms >> 14) * 1000) & _HIGH_MASK) << 14)) & _TICKS_MASK

    def ticks_diff(self, a, b):
        return ((a - b + _TICKS_HALF) & _TICKS_MASK) - _TICKS_HALF

    def ticks_add(self, a, delta):
        return (a + delta) & _TICKS_MASK
