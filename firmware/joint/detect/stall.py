"""Stall detection on the closed-loop PID error, as the original firmware does it (stall.h).

Every sample: |PID error| with spike rejection (a jump of more than `spike_limit` over the last
accepted sample reuses that sample), a low-pass filter, and a speed-adaptive threshold
`slope * speed + sensitivity * scale + (window_offset if window_low <= |speed| <= window_high)`,
speed in motor rad/s from the encoder. The filtered error above the threshold is a stall.

The original computes in floats; here every sample is small-int fixed point (usteps Q4, filter
state Q12, speed rad/s Q18), so sampling allocates nothing on the board, where floats are boxed.
The float properties (the log, the tests) are computed only when read; the trace formats the ints
(trace_line.py).
"""

RPM_PER_RAD_S = 9.549296596425384
_INPUT_MAX = 32767  # usteps: the filter's input is clamped here, far above any threshold
_SMALL_MAX = (1 << 30) - 1
_SPEED_Q = 18  # rad/s
_RPM_Q16_TO_SPEED_Q15 = round((1 << _SPEED_Q) / (RPM_PER_RAD_S * 65536) * 32768)


def _mul_q15(a, b):
    """a * b / 2**15, rounded, without leaving the small-int range: |a| < 2**30, 0 <= b < 2**15."""
    return (a >> 15) * b + (((a & 0x7FFF) * b + 0x4000) >> 15)


def speed_q18(rpm_q16):
    """Motor rad/s Q18 of a speed in rpm Q16 (fixed.RPM_Q)."""
    return _mul_q15(rpm_q16, _RPM_Q16_TO_SPEED_Q15)


def _q(value, bits):
    return max(-_SMALL_MAX, min(_SMALL_MAX, round(value * (1 << bits))))


class StallDetector:
    def __init__(self, cfg):
        ratio = cfg.sample_time / cfg.time_constant  # config: sample_time < time_constant
        self._take = max(1, min(32767, round(ratio * 32768)))
        self._keep = 32768 - self._take
        self._gain = max(0, min(32767, round(cfg.gain * 256)))  # Q8
        self._spike = int(cfg.spike_limit)  # |error| is whole usteps: > limit == > floor(limit)
        self._scale = _q(cfg.sensitivity_scale, 4)
        self._offset = _q(cfg.window_offset, 4)
        self._low = _q(cfg.window_low, _SPEED_Q)
        self._high = _q(cfg.window_high, _SPEED_Q)
        slope = _q(cfg.slope, 4)
        self._slope_hi, self._slope_lo = slope >> 15, slope & 0x7FFF
        self.sensitivity = 0
        self.last = 0
        self._state = 0  # filter, usteps Q12 at unit gain
        # The last sample, the columns the original printed for its serial plotter.
        self.raw = 0
        self.despiked = 0
        self.filtered_q4 = 0
        self.speed_q18 = 0
        self.set_rpm_q16 = 0
        self.threshold_q4 = 0
        self.stalled = False

    def _threshold_q4(self, speed):
        thr = (speed >> 3) * self._slope_hi + _mul_q15(speed >> 3, self._slope_lo)
        thr += self.sensitivity * self._scale
        if self._low <= abs(speed) <= self._high:
            thr += self._offset
        return thr

    def threshold_at(self, speed_rad_s):
        """The threshold (usteps) at an encoder speed in motor rad/s."""
        return self._threshold_q4(_q(speed_rad_s, _SPEED_Q)) / 16

    def update(self, pid_error, encoder_rpm, set_rpm):
        """Feed one sample: PID error in usteps, speeds in rpm Q16 (fixed.RPM_Q), all ints as the
        HAL gives them; True when it detects a stall (the filter is then reset)."""
        speed = speed_q18(encoder_rpm)
        raw = abs(pid_error)
        sample = self.last if raw - self.last > self._spike else raw
        state = _mul_q15(self._state, self._keep) + _mul_q15(min(sample, _INPUT_MAX) << 12, self._take)
        self._state = state
        filtered = _mul_q15(state >> 1, self._gain)
        thr = self._threshold_q4(speed)
        stalled = filtered > thr
        self.raw, self.despiked, self.filtered_q4 = raw, sample, filtered
        self.speed_q18, self.set_rpm_q16, self.threshold_q4 = speed, set_rpm, thr
        self.stalled = stalled
        if stalled:
            self.reset()
        else:
            self.last = sample
        return stalled

    def reset(self):
        self._state = 0
        self.last = 0

    @property
    def filtered(self):
        """The filtered |PID error| of the last sample, usteps."""
        return self.filtered_q4 / 16

    @property
    def threshold(self):
        """The threshold the last sample was compared with, usteps."""
        return self.threshold_q4 / 16

    @property
    def speed(self):
        """The encoder speed of the last sample, motor rad/s."""
        return self.speed_q18 / (1 << _SPEED_Q)

    @property
    def set_speed(self):
        """The set speed at the last sample, motor rad/s."""
        return self.set_rpm_q16 / 65536.0 / RPM_PER_RAD_S
