"""Signal filters of the original firmware (filters.h)."""


class Lowpass:
    """First-order IIR low-pass: x <- (1 - Ts/tau) * x + K * (Ts/tau) * u."""

    def __init__(self, gain, sample_time, time_constant):
        ratio = sample_time / time_constant
        self._keep = 1.0 - ratio
        self._take = gain * ratio
        self.value = 0.0

    def update(self, sample):
        self.value = self._keep * self.value + self._take * sample
        return self.value

    def reset(self):
        self.value = 0.0


class MovMax:
    """Maximum of the last `window` samples; the history starts at 0, so it never returns < 0."""

    def __init__(self, window):
        if window < 1:
            raise ValueError("MovMax window must be >= 1")
        self._ring = [0.0] * window
        self._next = 0

    def update(self, sample):
        self._ring[self._next] = sample
        self._next = (self._next + 1) % len(self._ring)
        return max(self._ring)

    def reset(self):
        for i in range(len(self._ring)):
            self._ring[i] = 0.0
        self._next = 0
