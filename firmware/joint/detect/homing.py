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

It cannot lie or push on (issue 20):

* evidence only with a push: a lag that comes from the encoder falling back (an overhauling load,
  J2 freewheeling with a payload, or a slipping motor) is no contact. HOMED needs the lag to have
  grown by `_PUSHED_USTEPS` while the encoder stood at its farthest point (the motor loaded
  against the stop), not only by the encoder falling away from it;
* bounded push: from the first lag of a contact (`_CONTACT_USTEPS`, a full step, after a push) the
  joint pushes at most `_PUSH_MS`; evidence without the sensitivity reached by then ends it
  PUSH_LIMIT;
* the encoder's own word first: a sensor that reports its magnet missing, too weak or too strong
  (the AS5600's MD/ML/MH) is refused before the motor moves (`check_magnet`: NO_MAGNET..);
* the joint must rest, and its encoder be quiet, before it starts (`rest` / `noisy`): a link still
  falling is refused (MOVING), and so is a reading that jumps by more than `_NOISE_USTEPS` against
  its trend (NOISY: a weak or missing magnet).

Integer arithmetic on preallocated state (the `TrackingDetector` inside).
"""

from .tracking import TrackingDetector, wrapped_diff
from ..micro import const

RUNNING = const(0)  # indices of protocol.HOMING_OUTCOMES
HOMED = const(1)
TRAVEL_LIMIT = const(2)
TIMEOUT = const(3)
PUSH_LIMIT = const(4)
NOISY = const(5)
MOVING = const(6)
NO_MAGNET = const(7)  # then WEAK_MAGNET 8, STRONG_MAGNET 9: NO_MAGNET - 1 + hal.MAGNET_*

_USTEPS_PER_DEG_Q8 = const(36409)  # 51200/360 usteps per degree, x 256
_MARGIN_MS = const(3000)
# A push: the lag grew by half the pull-out load angle (a full step, 256 usteps) while the encoder
# stayed within two full steps of its farthest point (a free motor lags far less; an encoder
# falling back leaves that point at once).
_PUSHED_USTEPS = const(128)
_AT_DEEPEST_USTEPS = const(512)
_CONTACT_USTEPS = const(256)
_PUSH_MS = const(1500)  # + the stop and a sample: under 2 s of pushing after the contact
# Peak-to-peak of the encoder at rest: noise (TLE5012B harsh 4 counts sigma = 6 usteps; AS5600
# 0.086 deg = 12 usteps) stays far below; a weak magnet (sigma x 20, ustepper-model.md 8.3) above.
_NOISE_USTEPS = const(160)
_MOVED_USTEPS = const(1024)  # an electrical period in the settle's second half: not at rest


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
        self._pushed = 0  # the largest lag while the encoder was at that point
        self._seen = False
        self._contact_ms = -1
        self._rest_prev = self._rest_prev2 = self._rest_first = self._rest_jump = 0
        self.outcome = RUNNING

    def rest(self, encoder, first):
        """Before start(), every main-loop pass while the motor holds: the largest jump of the
        reading against its trend (|second difference|, usteps), which a drift or a slow fall
        does not make, a noisy encoder does."""
        if first:
            self._rest_prev = self._rest_prev2 = self._rest_first = encoder
            self._rest_jump = 0
            return
        jump = encoder - 2 * self._rest_prev + self._rest_prev2
        if jump < 0:
            jump = -jump
        if jump > self._rest_jump:
            self._rest_jump = jump
        self._rest_prev2 = self._rest_prev
        self._rest_prev = encoder

    def check_magnet(self, magnet):
        """A HOME's first check: `magnet` is MotorHAL.magnet()'s code; the outcome so far,
        RUNNING for MAGNET_OK (0), else the refusal that names the magnet's fault."""
        self.outcome = NO_MAGNET - 1 + magnet if magnet else RUNNING
        return self.outcome

    def noisy(self):
        """True if the joint is not fit to home: it moved while held (MOVING: sampled motion also
        makes jumps) or the reading jumped more than a magnet in place allows (NOISY)."""
        moved = self._rest_prev - self._rest_first
        if moved > _MOVED_USTEPS or -moved > _MOVED_USTEPS:
            self.outcome = MOVING
        elif self._rest_jump > _NOISE_USTEPS:
            self.outcome = NOISY
        return self.outcome != RUNNING

    def start(self, direction, speed_rpm, sensitivity, field, encoder):
        """A homing toward `direction` (+1/-1) at `speed_rpm` (>= 1) starts driving now; encoder
        and field in usteps."""
        self._direction = direction
        self.deepest = encoder
        self._pushed = 0
        self._sensitivity = sensitivity
        self._elapsed = 0
        self._timeout = self._travel_ms_per_rpm // speed_rpm + _MARGIN_MS
        self._travel = 0
        self._e = encoder
        self.start_encoder = encoder
        self._seen = False
        self._contact_ms = -1
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
        evidence = track.update(field, encoder)
        if (self.deepest - encoder) * self._direction <= _AT_DEEPEST_USTEPS and track.lag > self._pushed:
            self._pushed = track.lag
        if evidence and self._seen and self._pushed >= _PUSHED_USTEPS:
            self.outcome = HOMED
        elif track.lag <= 0:
            self._seen = False  # the PID evidence and the push must come with this contact
            self._pushed = 0
            self._contact_ms = -1
        if self.outcome == RUNNING and track.lag > _CONTACT_USTEPS and self._pushed >= _PUSHED_USTEPS:
            if self._contact_ms < 0:
                self._contact_ms = elapsed_ms
            elif elapsed_ms - self._contact_ms > _PUSH_MS:
                self.outcome = PUSH_LIMIT
        if self.outcome == RUNNING:
            if self._travel > self._max_travel or -self._travel > self._max_travel:
                self.outcome = TRAVEL_LIMIT
            elif self._elapsed > self._timeout:
                self.outcome = TIMEOUT
        return self.outcome

    @property
    def lag(self):
        return self._track.lag
