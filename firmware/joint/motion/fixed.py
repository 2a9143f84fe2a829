"""Fixed-point numbers for the 1 kHz path: every float on the board is a heap object, ints are not.

A value in "Qn" is the integer round(x * 2**n). Every result and every intermediate here stays a
small int (|v| <= 2**30 - 1 on 32-bit ports), so nothing allocates. The legacy wire carries IEEE
float32; `f32_to_q` and `store_q` convert on its bits, so the bytes are exactly those of
struct.pack("<f", n / 2**q).

    ANGLE_Q   motor degrees          (Q12: 1/4096 degree, up to +-262 143 degrees)
    RPM_Q     motor rpm              (Q16: up to +-16 383 rpm)
    STEPS_Q   full steps/s and /s^2  (Q4)
"""

import struct

from ..micro import const, micropython, ptr32, ptr8

ANGLE_Q = const(12)
RPM_Q = const(16)
STEPS_Q = const(4)
LIMIT = const(0x3FFFFFFF)  # the largest small int on 32-bit ports


def muldiv(a, num, den):
    """floor(a * num / den) for a >= 0 and num * den < 2**30, without a long intermediate."""
    q = a // den
    return q * num + (a - q * den) * num // den


def i32(buf, off):
    """The little-endian int32 at buf[off:off + 4] (a long int, allocated, only beyond +-2**30)."""
    hi = buf[off + 3]
    low = buf[off] | (buf[off + 1] << 8) | (buf[off + 2] << 16)
    if hi < 0x40:
        return (hi << 24) | low
    if hi >= 0xC0:
        return ((hi - 256) << 24) | low
    return struct.unpack_from("<i", buf, off)[0]


@micropython.viper
def f32_to_q(buf: ptr8, off: int, q: int) -> int:
    """round(x * 2**q) of the little-endian float32 x at buf[off:off + 4], saturated to +-LIMIT.
    NaN and infinities (rejected by the protocol's checks before this runs) saturate too.
    Viper: it decodes every SETRPM/MOVETOANGLE a host streams (~60 us as Python on the chip)."""
    b3 = buf[off + 3]
    b2 = buf[off + 2]
    exp = ((b3 & 0x7F) << 1) | (b2 >> 7)
    if exp == 0:
        return 0  # zero or a denormal: below 2**-126
    mant = ((b2 & 0x7F) << 16) | (buf[off + 1] << 8) | buf[off] | 0x800000
    # x = mant * 2**(exp - 150); the result is mant * 2**(exp - 150 + q), rounded half away.
    shift = exp - 150 + q
    if shift >= 0:
        limit = 1
        limit = (limit << 30) - 1  # LIMIT, built at run time: no literal beyond 2**29 in viper
        value = limit if shift > 6 else mant << shift  # mant < 2**24: at most 2**30 - 1 after <<6
        if value > limit:
            value = limit
    elif shift < -25:
        value = 0
    else:
        value = ((mant >> (0 - shift - 1)) + 1) >> 1
    return 0 - value if b3 & 0x80 else value


@micropython.viper
def store_q(buf, n: int, q: int):
    """Write float32(n / 2**q) little-endian into the 4 bytes of `buf` for |n| <= LIMIT,
    0 <= q <= 30: exactly struct.pack("<f", n / 2**q) (rounded to nearest, ties to even, beyond
    2**24), in machine integers: float32(m * 2**(e - 150)), m the 24-bit mantissa, e the biased
    exponent. One aligned 32-bit store (a reply cache starts its wire buffer, a heap block of its own): an
    interrupt sees the old value or the new one, never a mix, so no critical section is needed."""
    p = ptr32(buf)
    if n == 0:
        p[0] = 0
        return
    sign = 0
    if n < 0:
        sign = 1
        n = 0 - n
    e = 150 - q
    m = n
    if n >= 0x1000000:
        s = 1
        while (n >> s) >= 0x1000000:
            s += 1
        m = n >> s
        rest = n - (m << s)
        half = 1 << (s - 1)
        if rest > half or (rest == half and (m & 1) != 0):
            m += 1
            if m == 0x1000000:
                m = 0x800000
                s += 1
        e += s
    else:
        while m < 0x8000:
            m <<= 8
            e -= 8
        while m < 0x800000:
            m <<= 1
            e -= 1
    p[0] = (m & 0x7FFFFF) | (e << 23) | (sign << 31)


def rescale(value, shift, limit):
    """round(value / 2**shift), half away from zero (as f32_to_q rounds), saturated to +-limit:
    a Q(n) value in Q(n - shift), for shift >= 1."""
    half = 1 << (shift - 1)
    if value >= 0:
        value = (value + half) >> shift
        return limit if value > limit else value
    value = (half - value) >> shift
    return -limit if value > limit else -value


def to_q(value, q):
    """round(value * 2**q) of a Python number (configuration time only: may allocate)."""
    scaled = value * (1 << q)
    return int(scaled + 0.5) if scaled >= 0 else -int(-scaled + 0.5)


def state_word(i):
    """A property over word i of the instance's int32 state array `s`: viper code works on the
    array, Python code off the 1 kHz path uses the names (the ramp's, the encoder's, the step
    generator's state)."""
    def get(self):
        return self.s[i]

    def put(self, value):
        self.s[i] = value
    return property(get, put)
