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

The extreme is kept by a monotonic queue (O(1) per sample, amortized), in one viper function over
preallocated word arrays (plain Python under CPython): inputs are counters that may wrap at 2**30;
the Q8 history is re-based before it could leave 32 bits, and a jump no motor makes in one sample
(a re-zeroed counter) starts the history afresh.
"""

from array import array

from ..micro import const, micropython

_WRAP = const(0x3FFFFFFF)
_HALF = const(0x20000000)
_SPAN = const(0x40000000)
_REBASE = const(0x4000000)  # |history| in Q8 beyond which it is shifted back to 0 (2**26)
_JUMP = const(0x40000)  # usteps per sample no motor turns: a re-zeroed counter, start afresh
# Signed words are stored biased by 2**29 (= _HALF): a viper ptr32 load does not sign-extend on a
# 64-bit machine (the unix port), and every stored value stays in 0 .. 2**30.
_BIAS = const(0x20000000)

# The state array: what one sample needs, in machine words for the viper step.
_F = const(0)  # last field, encoder
_E = const(1)
_Z = const(2)  # (s << 8) - slope * field, re-based now and then; biased
_DIR = const(3)  # direction of motion + 1
_OVER = const(4)
_HEAD = const(5)  # the queue in the ring: first slot, length
_COUNT = const(6)
_K = const(7)  # sample number (30 bits)
_ANCHORED = const(8)
_N = const(9)  # window, samples
_BASE = const(10)
_TAU_Q8 = const(11)  # tau_ms / sample_ms, Q8
_ADF_MAX = const(12)  # the largest |df| whose allowance cannot overflow
_CAP = const(13)
_SLOPE = const(14)
_CONFIRM = const(15)
_LAG = const(16)  # trace of the last sample
_THR = const(17)
_SPEED = const(18)  # biased
_STALLED = const(19)
_IN_F = const(20)  # this sample's inputs
_IN_E = const(21)
_WRAP_W = const(22)  # _WRAP, _HALF
_HALF_W = const(23)
_WORDS = const(24)

try:
    ptr32  # noqa: B018 -- a viper type, known to MicroPython's compiler only
except NameError:
    ptr32 = None


def wrapped_diff(a, b):
    """a - b for counters wrapping at 2**30, in -2**29 .. 2**29 - 1."""
    d = (a - b) & _WRAP
    return d - _SPAN if d >= _HALF else d


@micropython.viper
def _step(st: ptr32, ring: ptr32) -> int:
    """One sample (st[_IN_F], st[_IN_E]) through the detector; 1 once stalled. `ring` holds the
    queue as (d * z, biased; sample number) pairs."""
    wrap = st[_WRAP_W]  # 2**30 - 1 and 2**29 are no small ints on every board: words
    half = st[_HALF_W]  # (also the bias of the signed words)
    field = st[_IN_F]
    encoder = st[_IN_E]
    if st[_ANCHORED] == 0:
        st[_ANCHORED] = 1
        st[_F] = field
        st[_E] = encoder
        st[_Z] = half
        return 0
    df = (field - st[_F]) & wrap
    if df >= half:
        df = df - half - half
    de = (encoder - st[_E]) & wrap
    if de >= half:
        de = de - half - half
    st[_F] = field
    st[_E] = encoder
    st[_SPEED] = df + half
    st[_LAG] = 0
    st[_STALLED] = 0
    if df > _JUMP or -df > _JUMP or de > _JUMP or -de > _JUMP:  # not a motion: start afresh
        st[_Z] = half
        st[_DIR] = 1
        st[_OVER] = 0
        st[_COUNT] = 0
        return 0
    z = st[_Z] - half + ((df - de) << 8) - st[_SLOPE] * df
    if df == 0:
        if z > _REBASE or -z > _REBASE:
            z = 0  # no history to keep
        st[_Z] = z + half
        st[_DIR] = 1
        st[_OVER] = 0
        st[_COUNT] = 0
        return 0
    n = st[_N]
    head = st[_HEAD]
    count = st[_COUNT]
    d = 1
    if df < 0:
        d = -1
    if d + 1 != st[_DIR]:
        st[_DIR] = d + 1
        st[_OVER] = 0
        count = 0
    if z > _REBASE or -z > _REBASE:  # shift the history: only differences count
        shift = d * z
        i = head
        j = 0
        while j < count:
            ring[2 * i] = ring[2 * i] - shift
            i += 1
            if i >= n:
                i = 0
            j += 1
        z = 0
    st[_Z] = z + half
    w = d * z + half
    k = (st[_K] + 1) & wrap
    st[_K] = k
    # Samples older than the window leave at the front; candidates no better than this one
    # leave at the back; this one joins.
    if count > 0 and ((k - ring[2 * head + 1]) & wrap) >= n:
        head += 1
        if head >= n:
            head = 0
        count -= 1
    tail = head + count - 1
    if tail >= n:
        tail -= n
    while count > 0 and ring[2 * tail] >= w:
        count -= 1
        tail -= 1
        if tail < 0:
            tail = n - 1
    tail += 1
    if tail >= n:
        tail = 0
    ring[2 * tail] = w
    ring[2 * tail + 1] = k
    count += 1
    st[_HEAD] = head
    st[_COUNT] = count
    lag = (w - ring[2 * head]) >> 8
    adf = df
    if df < 0:
        adf = -df
    thr = st[_CAP]
    if adf <= st[_ADF_MAX]:
        allowance = (adf * st[_TAU_Q8]) >> 8
        if allowance < thr:
            thr = allowance
    thr += st[_BASE]
    st[_LAG] = lag
    st[_THR] = thr
    over = 0
    if lag > thr:
        over = st[_OVER] + 1
    st[_OVER] = over
    if over >= st[_CONFIRM]:
        st[_STALLED] = 1
        return 1
    return 0


class TrackingDetector:
    """base, cap: usteps; tau_ms: speed allowance in ms of field travel; window, confirm:
    samples; sample_ms: the sampling period the caller keeps (used for the speed allowance);
    slope_q8: the encoder error allowed per ustep of travel, /256."""

    def __init__(self, base, tau_ms, window, confirm, sample_ms, cap=1 << 28, slope_q8=0):
        n = max(1, int(window))
        st = array("i", [0] * _WORDS)
        tau_q8 = int(tau_ms) * 256 // max(1, int(sample_ms))
        st[_N] = n
        st[_BASE] = int(base)
        st[_TAU_Q8] = tau_q8
        st[_ADF_MAX] = _WRAP // max(1, tau_q8)
        st[_CAP] = min(int(cap), _WRAP - int(base))
        st[_SLOPE] = int(slope_q8)
        st[_CONFIRM] = int(confirm)
        st[_DIR] = 1
        st[_Z] = st[_SPEED] = _BIAS
        st[_WRAP_W] = _WRAP
        st[_HALF_W] = _HALF
        self._st = st
        self._ring = array("i", [0] * (2 * n))
        self.base = int(base)
        self.tau_ms = int(tau_ms)
        self.sample_ms = int(sample_ms)
        self.confirm = int(confirm)
        self.slope_q8 = int(slope_q8)

    @property
    def lag(self):
        """Trace of the last sample: the lag, the threshold and the field travel (usteps)."""
        return self._st[_LAG]

    @property
    def threshold(self):
        return self._st[_THR]

    @property
    def speed(self):
        return self._st[_SPEED] - _BIAS

    @property
    def stalled(self):
        return self._st[_STALLED] != 0

    def reset(self):
        """Forget the history (after a stop, a re-arm or an encoder re-zero). Cheap when there is
        none: the main loop calls it every sample while the detector is off."""
        st = self._st
        if st[_ANCHORED] == 0:  # nothing fed since the last reset
            return
        st[_ANCHORED] = 0
        st[_DIR] = 1
        st[_OVER] = 0
        st[_COUNT] = 0
        st[_LAG] = 0
        st[_STALLED] = 0

    def update(self, field, encoder):
        """Feed one sample; True once the encoder has not followed for `confirm` samples."""
        st = self._st
        st[_IN_F] = field & _WRAP  # the differences are taken modulo 2**30 anyway
        st[_IN_E] = encoder & _WRAP
        return _step(st, self._ring) != 0
