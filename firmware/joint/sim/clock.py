"""Virtual time for simulation: advanced explicitly, never by the wall clock."""


class VirtualClock:
    """Microsecond clock with the `time.ticks_*` interface the firmware uses."""

    def __init__(self, start_us=0):
        self.now_us = start_us

    def ticks_us(self):
        return self.now_us

    def ticks_ms(self):
        return self.now_us // 1000

    def ticks_diff(self, a, b):
        return a - b

    def ticks_add(self, a, delta):
        return a + delta

    def advance(self, us):
        if us < 0:
            raise ValueError("virtual time cannot go backwards")
        self.now_us += us

    def seconds(self):
        return self.now_us / 1e6
