"""When a homing may end: evidence of the end stop, or a limit that says there is none.

The original ended HOME on one raw |PID error| sample above the sensitivity, which encoder noise,
an acceleration or a load fakes at low sensitivities (and which never comes at high ones, since the
closed loop bounds the error). Here the end stop is where the encoder stops following the driver:

* evidence: the field has run ahead of the encoder by `evidence_usteps` (more than any load angle,
  noise or encoder error explains: a free stepper lags by under 256 usteps) for `confirm` samples
  in a row, and |PID error| exceeded the sensitivity since the lag began (the byte keeps its
  meaning: a higher one asks for a harder contact);
* no end stop: the encoder travelled farther than `max_travel_deg` (the joint's whole range), or
  the homing ran longer than that travel takes at the homing speed (x 1.5, + 3 s).

Integer arithmetic on preallocated state (the `TrackingDetector` inside).
"""

from .tracking import TrackingDetector, wrapped_diff
from ..micro import const

RUNNING = const(0)
HOMED = const(1)
TRAVEL_LIMIT = const(2)
TIMEOUT = const(3)
OUTCOMES = ("running", "homed", "travel limit reached without finding the end stop",
            "timeout without finding the end stop")

_USTEPS_PER_DEG_Q8 = const(36409)  # 51200/360 usteps per degree, x 256
_MARGIN_MS = const(3000)


class HomingMonitor:
    def __init__(self, homing_cfg, stall_cfg):
        self.sample_ms = stall_cfg.track_sample_ms
        self._track = TrackingDetector(homing_cfg.evidence_usteps, 0, stall_cfg.track_window,
                                       homing_cfg.confirm, self.sample_ms)
        self._max_travel = int(homing_cfg.max_travel_deg * _USTEPS_PER_DEG_Q8) >> 8
        self._travel_ms_per_rpm = int(homing_cfg.max_travel_deg * 250)  # deg / (6 deg/s per rpm) * 1.5
        self._sensitivity = 0
        self._elapsed = 0
        self._timeout = 0
        self._travel = 0
        self._e = 0
        self.start_encoder = 0
        self._direction = 1
        self.deepest = 0  # the encoder's farthest point in the homing direction: the end stop
        self._seen = False
        self.outcome = RUNNING

    def start(self, direction, speed_rpm, sensitivity, field, encoder):
        """A homing toward `direction` (+1/-1) at `speed_rpm` (>= 1) starts driving now; encoder
        and field in usteps."""
        self._direction = direction
        self.deepest = encoder
        self._sensitivity = sensitivity
        self._elapsed = 0
        self._timeout = self._travel_ms_per_rpm // speed_rpm + _MARGIN_MS
        self._travel = 0
        self._e = encoder
        self.start_encoder = encoder
        self._seen = False
        self.outcome = RUNNING
        self._track.reset()
        self._track.update(field, encoder)

    def watch(self, pid_error, encoder):
        """Every main-loop iteration: whether |PID error| exceeded the sensitivity, and the
        encoder's farthest point in the homing direction (where the stop is)."""
        if pid_error > self._sensitivity or -pid_error > self._sensitivity:
            self._seen = True
        if (encoder - self.deepest) * self._direction > 0:
            self.deepest = encoder

    def sample(self, field, encoder, elapsed_ms):
        """Every `sample_ms`, `elapsed_ms` after start(): the outcome so far (RUNNING until one)."""
        self._elapsed = elapsed_ms
        de = wrapped_diff(encoder, self._e)
        self._e = encoder
        self._travel += de
        track = self._track
        if track.update(field, encoder) and self._seen:
            self.outcome = HOMED
        elif track.lag <= 0:
            self._seen = False  # the PID evidence must come with this contact
        if self.outcome == RUNNING:
            if self._travel > self._max_travel or -self._travel > self._max_travel:
                self.outcome = TRAVEL_LIMIT
            elif self._elapsed > self._timeout:
                self.outcome = TIMEOUT
        return self.outcome

    @property
    def lag(self):
        return self._track.lag
