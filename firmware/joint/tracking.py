"""Stall detection by tracking: the encoder stopped following the driver's field.

A stepper follows its coil field within the load angle: less than one full step (256 usteps)
while it holds synchronism, whatever the speed, acceleration or load. A collision that stops the
rotor, or an overload that makes it slip poles, lets the field run away from the encoder at the
commanded speed. So, per sample, with `field` the usteps the driver has turned the field (never
relabelled by the closed loop) and `encoder` the measured position in usteps:

    lag = (field - encoder) now - its extreme since the motion in this direction began,
          over at most the last `window` samples, taken in the direction of motion
    stalled when lag > base + min(|field speed| * tau, cap) for `confirm` samples in a row

The window keeps the encoder's slow harmonic error out at low speed; the speed term covers its
faster swing at higher speeds, up to `cap` (the error's full swing: it cannot change by more within
any window), where the lag of a blocked rotor grows by thousands of usteps per sample anyway. A reversal restarts the extreme (the load angle does not change sign
through one: decelerating and accelerating the other way take torque the same way). Nothing is
judged while the field stands still.

Integer arithmetic on preallocated state only: inputs are counters that may wrap at 2**30.
"""

from array import array

try:
    from micropython import const
except ImportError:
    def const(value):
        return value

_WRAP = const(0x3FFFFFFF)
_HALF = const(0x20000000)
_SPAN = const(0x40000000)


def wrapped_diff(a, b):
    """a - b for counters wrapping at 2**30, in -2**29 .. 2**29 - 1."""
    d = (a - b) & _WRAP
    return d - _SPAN if d >= _HALF else d


class TrackingDetector:
    """base, cap: usteps; tau_ms: speed allowance in ms of field travel; window, confirm:
    samples; sample_ms: the sampling period the caller keeps (used for the speed allowance)."""

    def __init__(self, base, tau_ms, window, confirm, sample_ms, cap=1 << 28):
        self.base = int(base)
        self.tau_ms = int(tau_ms)
        self.cap = int(cap)
        self.sample_ms = int(sample_ms)
        self.confirm = int(confirm)
        self._ring = array("i", [0] * max(1, int(window)))
        self._n = len(self._ring)
        self._i = 0
        self._f = 0
        self._e = 0
        self._s = 0
        self._dir = 0
        self._over = 0
        self._anchored = False
        # Trace of the last sample (usteps).
        self.lag = 0
        self.threshold = 0
        self.speed = 0  # field travel in the last sample
        self.stalled = False

    def reset(self):
        """Forget the history (after a stop, a re-arm or an encoder re-zero)."""
        self._anchored = False
        self._dir = 0
        self._over = 0
        self.lag = 0
        self.stalled = False

    def update(self, field, encoder):
        """Feed one sample; True once the encoder has not followed for `confirm` samples."""
        if not self._anchored:
            self._anchored = True
            self._f = field
            self._e = encoder
            self._s = 0
            return False
        df = wrapped_diff(field, self._f)
        de = wrapped_diff(encoder, self._e)
        self._f = field
        self._e = encoder
        s = self._s + df - de
        self._s = s
        self.speed = df
        if df == 0:
            self._dir = 0
            self._over = 0
            self.lag = 0
            self.stalled = False
            return False
        ring = self._ring
        n = self._n
        d = 1 if df > 0 else -1
        if d != self._dir:
            self._dir = d
            self._over = 0
            for k in range(n):
                ring[k] = s
        ring[self._i] = s
        self._i = (self._i + 1) % n
        ext = ring[0]
        if d > 0:
            for k in range(1, n):
                if ring[k] < ext:
                    ext = ring[k]
            lag = s - ext
        else:
            for k in range(1, n):
                if ring[k] > ext:
                    ext = ring[k]
            lag = ext - s
        allowance = (df if df > 0 else -df) * self.tau_ms // self.sample_ms
        thr = self.base + (allowance if allowance < self.cap else self.cap)
        self.lag = lag
        self.threshold = thr
        if lag > thr:
            self._over += 1
        else:
            self._over = 0
        self.stalled = self._over >= self.confirm
        return self.stalled
