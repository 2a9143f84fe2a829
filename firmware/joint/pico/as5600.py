"""AS5600 magnetic angle sensor on I2C: raw angle, magnet status, multi-turn count.

Registers (ams AS5600 datasheet): RAW ANGLE 0x0C/0x0D (12 bits, high nibble first), STATUS 0x0B
(MD bit 5 magnet detected, ML bit 4 too weak, MH bit 3 too strong), CONF 0x07/0x08. The raw
angle increases clockwise seen from the magnet side with DIR tied low; the firmware does not care,
because the orientation check flips the driver (GCONF.shaft) to match the encoder.

The address pointer does not advance past RAW ANGLE (nor ANGLE, MAGNITUDE), so once it points
there `sample()` reads without writing it again: 29 bit times instead of 48 on the bus that blocks
the 1 kHz loop. Any other access, or a failed one, sets the pointer again on the next sample.

Units: 4096 counts per revolution. With the library's 51200 usteps per revolution one count is
12.5 usteps (0.0879 degrees), 8x coarser than the uStepper's TLE5012B (1.5625 usteps).
"""

from ..emitters import micropython

try:
    from micropython import const
except ImportError:
    def const(x):
        return x

ADDRESS = const(0x36)
CONF = const(0x07)
STATUS = const(0x0B)
RAW_ANGLE = const(0x0C)

COUNTS_PER_REV = const(4096)
_HALF = const(2048)
USTEPS_PER_COUNT = 51200 / 4096  # 12.5 exactly
DEGREES_PER_COUNT = 360.0 / 4096

_MH = const(0x08)
_ML = const(0x10)
_MD = const(0x20)

def conf_word(slow_filter, fast_threshold):
    """CONF (16 bits, 0x07 high byte): SF bits 9:8, FTH bits 12:10; power mode NOM, no
    hysteresis, analog output, watchdog off.

    SF 0..3 = 16x, 8x, 4x, 2x slow filter, settling in 2.2, 1.1, 0.55, 0.286 ms: the settling
    time is encoder lag, which the closed loop sees as error at speed (v * lag). FTH 0 = slow
    filter only; 1..7 pick the step (6, 7, 9, 18, 21, 24, 10 LSB) above which the fast filter
    takes over."""
    return ((slow_filter & 3) << 8) | ((fast_threshold & 7) << 10)


def decode_status(status):
    """(detected, too_weak, too_strong) from the STATUS byte."""
    return bool(status & _MD), bool(status & _ML), bool(status & _MH)


def unwrap(prev, raw):
    """Signed count change from `prev` to `raw`, taking the shorter way round (|d| <= 2048)."""
    d = (raw - prev) & 0xFFF
    return d - COUNTS_PER_REV if d > _HALF else d


def counts_to_usteps(counts):
    """int(12.5 * counts), truncated toward zero like the library's int32 cast."""
    return int(counts * 12.5)


class AS5600:
    """Reads one AS5600 through a machine.I2C-like object and keeps a multi-turn count.

    `count` is the angle since home in counts (never wraps); `sample()` reads once and returns
    False when the bus failed, leaving the count as it was (the library drops such a sample).
    """

    def __init__(self, i2c, address=ADDRESS):
        self._i2c = i2c
        self._address = address
        self._buf = bytearray(2)
        self._status = bytearray(1)
        self.raw = 0
        self.count = 0
        self.errors = 0
        self._at_raw = False  # the device's address pointer is at RAW ANGLE

    def configure(self, slow_filter, fast_threshold):
        """Write CONF (volatile; nothing is burnt) and read it back; OSError if it did not stick."""
        word = conf_word(slow_filter, fast_threshold)
        self._at_raw = False
        buf = self._buf
        buf[0] = word >> 8
        buf[1] = word & 0xFF
        self._i2c.writeto_mem(self._address, CONF, buf)
        self._i2c.readfrom_mem_into(self._address, CONF, buf)
        got = ((buf[0] << 8) | buf[1]) & 0x3FFF
        if got != word:
            raise OSError("AS5600 CONF reads back 0x%04x, wrote 0x%04x" % (got, word))

    def status(self):
        self._at_raw = False
        self._i2c.readfrom_mem_into(self._address, STATUS, self._status)
        return self._status[0]

    def read_raw(self):
        buf = self._buf
        self._at_raw = False
        self._i2c.readfrom_mem_into(self._address, RAW_ANGLE, buf)
        self._at_raw = True
        return ((buf[0] & 0x0F) << 8) | buf[1]

    def start(self):
        """Take the current angle as the reference and zero the count (OSError propagates)."""
        self.raw = self.read_raw()
        self.count = 0

    def set_home(self):
        """Zero the count at the last sampled angle, as the library takes its offset then."""
        self.count = 0

    @micropython.native
    def sample(self):
        """One reading (1 kHz: read_raw and unwrap inlined, each call costs tens of us on the chip)."""
        buf = self._buf
        try:
            if self._at_raw:
                self._i2c.readfrom_into(self._address, buf)
            else:
                self._i2c.readfrom_mem_into(self._address, RAW_ANGLE, buf)
                self._at_raw = True
        except OSError:
            self._at_raw = False
            self.errors += 1
            return False
        raw = ((buf[0] & 0x0F) << 8) | buf[1]
        d = (raw - self.raw) & 0xFFF
        self.count += d - COUNTS_PER_REV if d > _HALF else d
        self.raw = raw
        return True

    def usteps(self):
        return counts_to_usteps(self.count)

    def degrees(self):
        return self.count * DEGREES_PER_COUNT
