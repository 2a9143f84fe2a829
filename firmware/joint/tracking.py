"""Stall detection by tracking: the encoder stopped following the driver's field.

A stepper follows its coil field within the load angle: less than one full step (256 usteps)
while it holds synchronism, whatever the speed, acceleration or load. A collision that stops the
rotor, or an overload that makes it slip poles, lets the field run away from the encoder at the
commanded speed. So, per sample, with `field` the usteps the driver has turned the field (never
relabelled by the closed loop), `encoder` the measured position in usteps and s = field - encoder:

    lag = the largest, over the samples i since the motion in this direction began (at most the
          last `window`), of  d * (s_now - s_i) - slope * |field_now - field_i|
    stalled when lag > base + min(|field speed| * tau, cap) for `confirm` samples in a row

(d: the direction of motion). The encoder's harmonic error (1x and 2x per revolution) changes s by
at most `slope` (Q8: /256) per ustep the rotor turns, so its share of a lag grows with the travel
between the two samples, not with time: the slope term takes it out at every speed, and `base` is
left with what the load angle, ringing and noise add. A blocked rotor's lag grows by one ustep per
ustep of field, far more than `slope`. The speed term (tau, capped) is a second, older allowance
for what grows with speed. A reversal restarts the history (the load angle does not change sign
through one: decelerating and accelerating the other way take torque the same way). Nothing is
judged while the field stands still.

The extreme is kept by a monotonic queue (O(1) per sample, amortized). Integer arithmetic on
preallocated state only: inputs are counters that may wrap at 2**30; the Q8 history is re-based
before it could leave MicroPython's small integers.
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
_REBASE = const(0x4000000)  # |history| in Q8 beyond which it is shifted back to 0 (2**26)


def wrapped_diff(a, b):
    """a - b for counters wrapping at 2**30, in -2**29 .. 2**29 - 1."""
    d = (a - b) & _WRAP
    return d - _SPAN if d >= _HALF else d


class TrackingDetector:
    """base, cap: usteps; tau_ms: speed allowance in ms of field travel; window, confirm:
    samples; sample_ms: the sampling period the caller keeps (used for the speed allowance);
    slope_q8: the encoder error allowed per ustep of travel, /256."""

    def __init__(self, base, tau_ms, window, confirm, sample_ms, cap=1 << 28, slope_q8=0):
        self.base = int(base)
        self.tau_ms = int(tau_ms)
        self.cap = int(cap)
        self.sample_ms = int(sample_ms)
        self.confirm = int(confirm)
        self.slope_q8 = int(slope_q8)
        n = max(1, int(window))
        self._n = n
        self._vals = array("i", [0] * n)  # the queue: d * z of candidate extremes, ascending
        self._when = array("i", [0] * n)  # their sample numbers
        self._head = 0
        self._count = 0
        self._k = 0  # sample number
        self._f = 0
        self._e = 0
        self._z = 0  # (s << 8) - slope * field, re-based now and then
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
        self._count = 0
        self.lag = 0
        self.stalled = False

    def update(self, field, encoder):
        """Feed one sample; True once the encoder has not followed for `confirm` samples."""
        if not self._anchored:
            self._anchored = True
            self._f = field
            self._e = encoder
            self._z = 0
            return False
        df = wrapped_diff(field, self._f)
        de = wrapped_diff(encoder, self._e)
        self._f = field
        self._e = encoder
        z = self._z + ((df - de) << 8) - self.slope_q8 * df
        self.speed = df
        if df == 0:
            self._z = z
            self._dir = 0
            self._over = 0
            self._count = 0
            self.lag = 0
            self.stalled = False
            return False
        n = self._n
        vals = self._vals
        when = self._when
        head = self._head
        count = self._count
        d = 1 if df > 0 else -1
        if d != self._dir:
            self._dir = d
            self._over = 0
            count = 0
        if z > _REBASE or z < -_REBASE:  # shift the history: only differences count
            shift = d * z
            i = head
            for _ in range(count):
                vals[i] -= shift
                i += 1
                if i >= n:
                    i = 0
            z = 0
        self._z = z
        w = d * z
        k = self._k + 1
        self._k = k
        # Samples older than the window leave at the front; candidates no better than this one
        # leave at the back; this one joins.
        if count and k - when[head] >= n:
            head += 1
            if head >= n:
                head = 0
            count -= 1
        tail = head + count - 1
        if tail >= n:
            tail -= n
        while count and vals[tail] >= w:
            count -= 1
            tail -= 1
            if tail < 0:
                tail = n - 1
        tail += 1
        if tail >= n:
            tail = 0
        vals[tail] = w
        when[tail] = k
        count += 1
        self._head = head
        self._count = count
        lag = (w - vals[head]) >> 8
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
