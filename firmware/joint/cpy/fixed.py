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
    exactly struct.pack("<f", n / 2**q): motion.fixed.store_q's rounding, byte by byte."""
    if n == 0:
        buf[0] = buf[1] = buf[2] = buf[3] = 0
        return
    sign = 0
    if n < 0:
        sign = 0x80
        n = -n
    e = 150 - q  # the biased exponent of the mantissa's lowest bit
    if n >= 0x1000000:
        s = 1
        while (n >> s) >= 0x1000000:
            s += 1
        m = n >> s
        rest = n - (m << s)
        half = 1 << (s - 1)
        if rest > half or (rest == half and m & 1):
            m += 1
            if m == 0x1000000:
                m = 0x800000
                s += 1
        e += s
    else:
        m = n
        while m < 0x8000:
            m <<= 8
            e -= 8
        while m < 0x800000:
            m <<= 1
            e -= 1
    buf[0] = m & 0xFF
    buf[1] = (m >> 8) & 0xFF
    buf[2] = ((m >> 16) & 0x7F) | ((e & 1) << 7)
    buf[3] = (e >> 1) | sign
