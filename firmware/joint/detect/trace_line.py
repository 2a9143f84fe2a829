"""One stall-detection sample as a line of the console's trace (debug_commands.TRACE_COLUMNS),
written from the detector's fixed-point ints into a preallocated buffer.

The line reads as the original's `%.2f`/`%.3f` columns did, but no float is boxed: formatting seven
floats took ~2 ms per line on the chip (soft float, a dozen allocations in a fragmented heap),
so at 100 samples a second the 1 kHz loop missed a fifth of its iterations. A line allocates
nothing: even a str or a memoryview slice per line cost 100-300 us in the running joint's heap.
"""

from array import array

from ..micro import const, micropython, ptr8
from .stall import speed_q18


# Per column: Q bits and decimals (raw, despiked, filtered, speed, set_speed, threshold, stall).
_COLUMNS = b"\x00\x02\x00\x02\x04\x02\x12\x03\x12\x03\x04\x02\x00\x00"
_N = const(7)
# At most 16 bytes a column: sign, 10 digits (|value| < 2**30), point, 3 decimals, tab.
_SIZE = const(112)


@micropython.viper
def put_line(buf: ptr8, values, columns: ptr8) -> int:
    """The _N values at buf[0:], tab-separated: value i as value / 2**q with d (0..3) decimals,
    halves rounded away from zero, (q, d) = columns[2i], columns[2i + 1] (q <= 18); returns the
    length. |value| < 2**30: every intermediate fits 32 bits."""
    pos = 0
    i = 0
    while i < _N:
        if i:
            buf[pos] = 9  # tab
            pos += 1
        value = int(values[i])  # an object, not a ptr32: ptr32 loads do not sign-extend on 64-bit ports
        q = columns[2 * i]
        decimals = columns[2 * i + 1]
        if value < 0:
            buf[pos] = 45  # "-"
            pos += 1
            value = 0 - value
        scale = 1
        n = decimals
        while n > 0:
            scale *= 10
            n -= 1
        whole = value >> q
        frac = ((value & ((1 << q) - 1)) * scale + ((1 << q) >> 1)) >> q
        if frac >= scale:
            whole += 1
            frac -= scale
        first = pos
        while True:  # the whole part's digits, last first
            buf[pos] = 48 + whole % 10
            pos += 1
            whole //= 10
            if whole == 0:
                break
        j = pos - 1
        while first < j:
            digit = buf[first]
            buf[first] = buf[j]
            buf[j] = digit
            first += 1
            j -= 1
        if decimals > 0:
            buf[pos] = 46  # "."
            pos += 1
            scale //= 10
            while scale > 0:
                buf[pos] = 48 + frac // scale
                pos += 1
                frac %= scale
                scale //= 10
        i += 1
    return pos


class TraceLine:
    """`line(detector)`: the StallDetector's last sample as one line (no newline), a memoryview
    of this object's buffer, valid until the next call. Nothing allocates: there is a view of
    every length, made once (about 2 KB of heap, only on a board whose trace was turned on)."""

    def __init__(self):
        self._buf = bytearray(_SIZE)
        view = memoryview(self._buf)
        self._views = [view[:n] for n in range(_SIZE + 1)]
        self._values = array("i", bytes(4 * _N))

    def line(self, s):
        v = self._values
        v[0] = s.raw
        v[1] = s.despiked
        v[2] = s.filtered_q4
        v[3] = s.speed_q18
        v[4] = speed_q18(s.set_rpm_q16)
        v[5] = s.threshold_q4
        v[6] = 1 if s.stalled else 0
        return self._views[put_line(self._buf, v, _COLUMNS)]
