"""motion.fixed.store_q for CircuitPython's bytecode, installed in its place by cpy/app.py.

The shared store_q is viper on MicroPython: one 32-bit store through ptr32, since the hard IRQ
may read the cache at any instruction. As bytecode on CircuitPython, ptr32 is a memoryview made
every call and the word's exponent and sign bits make long ints (small ints are 31 bits there):
about 45 bytes and 148 us a call, twice an iteration (bench/chip_cp_profile.py). Here the four
bytes are written one at a time, every value a small int; nothing interrupts the loop on
CircuitPython (the bus is served by the loop itself), so a reply never sees half a value.
"""


def store_q(buf, n, q):
    """float32(n / 2**q) little-endian into buf[0:4] for |n| <= fixed.LIMIT, 0 <= q <= 30,
    exactly struct.pack("<f", n / 2**q) (rounded to nearest, ties to even, beyond 2**24). The
    top bit is found by halving steps rather than by motion.fixed's shifting loops: no loop, so
    every value costs the same few bytecodes."""
    if n == 0:
        buf[0] = buf[1] = buf[2] = buf[3] = 0
        return
    sign = 0
    if n < 0:
        sign = 0x80
        n = -n
    top = 0  # the index of n's highest set bit, 0..29
    if n >> 16:
        top = 16
    if n >> (top + 8):
        top += 8
    if n >> (top + 4):
        top += 4
    if n >> (top + 2):
        top += 2
    if n >> (top + 1):
        top += 1
    exponent = 127 + top - q  # biased: the value's highest bit is 2**(top - q)
    if top > 23:  # more than the 24 bits of a float32's mantissa: round to nearest, ties to even
        shift = top - 23
        mantissa = n >> shift
        rest = n - (mantissa << shift)
        half = 1 << (shift - 1)
        if rest > half or (rest == half and mantissa & 1):
            mantissa += 1
            if mantissa == 0x1000000:  # rounded up to the next power of two
                mantissa = 0x800000
                exponent += 1
    else:
        mantissa = n << (23 - top)
    buf[0] = mantissa & 0xFF
    buf[1] = (mantissa >> 8) & 0xFF
    buf[2] = ((mantissa >> 16) & 0x7F) | ((exponent & 1) << 7)
    buf[3] = (exponent >> 1) | sign
