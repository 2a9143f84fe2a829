"""Stall detection on the closed-loop PID error, as the original firmware does it (stall.h).

Every sample: |PID error| with spike rejection (a jump of more than `spike_limit` over the last
accepted sample reuses that sample), a low-pass filter, and a speed-adaptive threshold
`slope * speed + sensitivity * scale + (window_offset if window_low <= |speed| <= window_high)`,
speed in motor rad/s from the encoder. The filtered error above the threshold is a stall.
"""

from .filters import Lowpass

RPM_PER_RAD_S = 9.549296596425384
_RPM_Q16_PER_RAD_S = RPM_PER_RAD_S * 65536


class StallDetector:
    def __init__(self, cfg):
        self._cfg = cfg
        self._filter = Lowpass(cfg.gain, cfg.sample_time, cfg.time_constant)
        self.sensitivity = 0
        self.last = 0.0
        # Trace of the last sample, the columns the original printed for its serial plotter.
        self.raw = 0.0
        self.despiked = 0.0
        self.filtered = 0.0
        self.speed = 0.0
        self.set_speed = 0.0
        self.threshold = 0.0
        self.stalled = False

    def threshold_at(self, speed_rad_s):
        cfg = self._cfg
        thr = cfg.slope * speed_rad_s + self.sensitivity * cfg.sensitivity_scale
        if cfg.window_low <= abs(speed_rad_s) <= cfg.window_high:
            thr += cfg.window_offset
        return thr

    def update(self, pid_error, encoder_rpm, set_rpm):
        """Feed one sample: PID error in usteps, speeds in rpm Q16 (fixed.RPM_Q, the HAL's
        units); True when it detects a stall (the filter is then reset)."""
        speed = encoder_rpm / _RPM_Q16_PER_RAD_S
        set_rpm = set_rpm / 65536.0
        raw = abs(pid_error)
        sample = self.last if raw - self.last > self._cfg.spike_limit else raw
        filtered = self._filter.update(sample)
        thr = self.threshold_at(speed)
        stalled = filtered > thr
        self.raw, self.despiked, self.filtered = raw, sample, filtered
        self.speed, self.set_speed, self.threshold = speed, set_rpm / RPM_PER_RAD_S, thr
        self.stalled = stalled
        if stalled:
            self.reset()
        else:
            self.last = sample
        return stalled

    def reset(self):
        self._filter.reset()
        self.last = 0.0
