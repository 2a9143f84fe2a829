"""Slow-contact detection: the load angle against itself one motor turn earlier.

A stepper pushing on something holds its rotor behind the coil field by the load angle, which
grows with the force: for J2 at 8 % current about 2 usteps per newton at the screw's nut. A soft
body part (the abdomen, 10 N/mm) loads the motor so slowly that the tracking detector cannot tell
it from the encoder's harmonic error (1x and 2x per motor turn, up to 270 usteps peak to peak): the
two grow at the same angle per ustep turned. But the harmonic error repeats every motor turn, at
the same rotor angle, and a free-running motor at a constant speed holds the same load angle at the
same rotor angle turn after turn. So, with s = field - encoder (usteps) and the motor turn cut into
TURN_BINS bins of the encoder's angle:

    baseline[bin]  d * s in this bin: a running mean (halfway per sample) over the first turn
                   at this speed, then following any lower sample a quarter of the way and
                   creeping up one ustep a visit (noise cannot drag it down; a contact grows
                   tens of usteps a turn)
    excess         d * s - baseline[bin]: the median of the last three samples, clipped, then
                   low-passed (2**_LOWPASS_SHIFT samples)
    loaded         excess > limit for `confirm` samples in a row

(d: the direction of motion). Whatever repeats with the rotor angle (the harmonic error, as raw or
calibrated as it is) cancels; what grows from one turn to the next (a body part squeezed) does not.
A growing contact is never learned as free motion (the baseline rises one ustep a visit). Any
change of the driver's speed (acceleration, reversal, a stop) forgets the baseline, since the load
angle depends on speed; so the first motor turn at a constant speed only learns, and a contact that
began within it is seen by its growth since (J2 at 10 rpm: about 37 N by then). One viper function
over preallocated arrays; the bin is computed by the caller (small-int arithmetic, no allocation).
"""

from array import array

from ..micro import const, micropython

TURN_USTEPS = const(51200)  # one motor turn: 200 full steps of 256 usteps
TURN_BINS = const(256)
BIN_USTEPS = const(200)  # TURN_USTEPS // TURN_BINS
_LOWPASS_SHIFT = const(3)  # the excess is low-passed over 2**3 samples (40 ms at 5 ms)
_Q = const(4)  # the low-passed excess is kept in Q4
_FOLLOW_SHIFT = const(2)  # the baseline follows a lower load angle by a quarter of it per sample
_EMPTY = const(0)  # a baseline bin not yet visited; stored values are biased by _TABLE_BIAS
_TABLE_BIAS = const(0x8000)  # ptr16 loads do not sign-extend
_SLIP = const(0x7000)  # |s| beyond this many usteps: a pole slip or a re-zero, start afresh

# The state array, machine words for the viper step (signed ones biased by _HALF as in tracking.py).
_SPEED = const(0)  # the driver's speed of the last sample, biased
_DIRTY = const(1)  # the baseline holds visited bins
_EXCESS = const(2)  # low-passed excess, Q4, biased
_OVER = const(3)  # samples in a row over the limit
_LIMIT = const(4)
_CLIP = const(5)  # the most one sample may add to the excess, usteps
_IN_F = const(6)  # this sample's inputs: field, encoder, baseline bin, driver speed (biased)
_IN_E = const(7)
_IN_BIN = const(8)
_IN_SPEED = const(9)
_WRAP_W = const(10)
_HALF_W = const(11)
_START = const(12)  # the field where this speed began
_BIN = const(13)  # the bin of the last sample
_X1 = const(14)  # the last two samples' excess (not low-passed), biased
_X2 = const(15)
_WORDS = const(16)

_WRAP = const(0x3FFFFFFF)
_HALF = const(0x20000000)

try:
    ptr16  # noqa: B018 -- viper types, known to MicroPython's compiler only
    ptr32  # noqa: B018
except NameError:
    ptr16 = ptr32 = None


@micropython.viper
def _step(st: ptr32, baseline: ptr16) -> int:
    """One sample through the detector: how many samples in a row the excess has been over the
    limit."""
    wrap = st[_WRAP_W]
    half = st[_HALF_W]
    speed = st[_IN_SPEED]
    s = (st[_IN_F] - st[_IN_E]) & wrap
    if s >= half:
        s = s - half - half
    if speed != st[_SPEED] or speed == half or s > _SLIP or -s > _SLIP:
        # A new speed (or none, or a lost turn): forget what this one learned.
        st[_SPEED] = speed
        st[_START] = st[_IN_F]
        st[_EXCESS] = st[_X1] = st[_X2] = half
        st[_OVER] = 0
        if st[_DIRTY]:
            st[_DIRTY] = 0
            i = 0
            while i < TURN_BINS:
                baseline[i] = _EMPTY
                i += 1
        return 0
    if speed < half:
        s = -s
    b = st[_IN_BIN]
    held = baseline[b]
    if held == _EMPTY:  # first visit at this speed: learn only
        baseline[b] = s + _TABLE_BIAS
        st[_DIRTY] = 1
        st[_BIN] = b
        return 0
    travel = (st[_IN_F] - st[_START]) & wrap
    if travel >= half:
        travel = half + half - travel
    x = s - (held - _TABLE_BIAS)
    visit = b != st[_BIN]
    st[_BIN] = b
    if travel < TURN_USTEPS:  # the first turn learns: the mean of its samples in each bin
        baseline[b] = held + (x >> 1)
        return 0
    if x < 0:  # less loaded than the baseline here: it follows, a quarter per sample (noise)
        baseline[b] = held + (x >> _FOLLOW_SHIFT)
    elif visit and x > 0:  # and creeps up one ustep a visit, so noise cannot drag it down
        baseline[b] = held + 1
    # The median of this sample's and the last two: a stale encoder sample (a skipped ISR tick,
    # v x 0.65 ms at speed) is one sample high, a contact stays.
    x1 = st[_X1] - half
    x2 = st[_X2] - half
    st[_X2] = x1 + half
    st[_X1] = x + half
    if x1 > x2:
        x1, x2 = x2, x1
    if x < x1:
        x = x1
    elif x > x2:
        x = x2
    clip = st[_CLIP]
    if x > clip:
        x = clip
    elif x < 0 - clip:
        x = 0 - clip
    excess = st[_EXCESS] - half
    excess += ((x << _Q) - excess) >> _LOWPASS_SHIFT
    st[_EXCESS] = excess + half
    if excess <= (st[_LIMIT] << _Q):
        st[_OVER] = 0
        return 0
    st[_OVER] += 1
    return st[_OVER]


class LoadAngleDetector:
    """limit: usteps of load angle over the free-running baseline; confirm: samples in a row;
    clip: the most one sample may add (an encoder spike), usteps."""

    def __init__(self, limit, confirm, clip):
        st = array("i", [0] * _WORDS)
        st[_LIMIT] = int(limit)
        st[_CLIP] = int(clip)
        st[_SPEED] = st[_EXCESS] = st[_X1] = st[_X2] = _HALF
        st[_WRAP_W] = _WRAP
        st[_HALF_W] = _HALF
        self._st = st
        self._baseline = array("H", [_EMPTY] * TURN_BINS)
        self.limit = int(limit)
        self.confirm = int(confirm)

    @property
    def excess(self):
        """The low-passed load angle over the baseline of the last sample, usteps."""
        return (self._st[_EXCESS] - _HALF) >> _Q

    def reset(self):
        """Forget the baseline (a stop, a re-arm, an encoder re-zero)."""
        st = self._st
        st[_SPEED] = st[_IN_SPEED] = _HALF
        st[_IN_F] = st[_IN_E] = 0
        _step(st, self._baseline)

    def update(self, field, encoder, speed):
        """Feed one sample: the driver's field and the encoder (usteps, counters that may wrap at
        2**30) and the driver's speed (any integer unit, 0 standing); True once loaded."""
        st = self._st
        st[_IN_F] = field & _WRAP
        st[_IN_E] = encoder & _WRAP
        st[_IN_BIN] = (encoder % TURN_USTEPS) // BIN_USTEPS
        st[_IN_SPEED] = speed + _HALF
        return _step(st, self._baseline) >= self.confirm
