"""Wall-clock time for the firmware: MicroPython's ticks, or a CPython stand-in for real-time simulation."""

import time

if hasattr(time, "ticks_ms"):
    class MonotonicClock:
        def __init__(self):
            self.ticks_ms = time.ticks_ms
            self.ticks_us = time.ticks_us
            self.ticks_diff = time.ticks_diff
            self.ticks_add = time.ticks_add
else:
    class MonotonicClock:
        def ticks_us(self):
            return time.monotonic_ns() // 1000

        def ticks_ms(self):
            return time.monotonic_ns() // 1000000

        def ticks_diff(self, a, b):
            return a - b

        def ticks_add(self, a, delta):
            return a + delta
