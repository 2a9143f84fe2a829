"""AS5600 magnetic angle sensor on I2C: raw angle, magnet status, multi-turn count.

Registers (ams AS5600 datasheet): RAW ANGLE 0x0C/0x0D (12 bits, high nibble first), STATUS 0x0B
(MD bit 5 magnet detected, ML bit 4 too weak, MH bit 3 too strong), CONF 0x07/0x08. The raw
angle increases clockwise seen from the magnet side with DIR tied low; the firmware does not care,
because the orientation check flips the driver (GCONF.shaft) to match the encoder.

The address pointer does not advance past RAW ANGLE (nor ANGLE, MAGNITUDE), so once it points
there `sample()` reads without writing it again: 29 bit times instead of 48 on the bus that blocks
the 1 kHz loop. Any other access, or a failed one, sets the pointer again on the next sample.

With `regs` (the address of the RP2040's DW_apb_i2c block that machine.I2C set up) a sample
does not wait for the wire either: `next_sample` takes the two bytes of the read queued at the
previous sample from the controller's RX FIFO and queues the next read (IC_DATA_CMD: read, read +
STOP), a few microseconds of CPU instead of ~80 us of wire time. The angle is then the one read on
the wire right after the previous sample, one sample period old: each read carries two words the
caller gives when it is queued (its positions at that instant) and gets back with the angle, so
the caller compares quantities of the same instant. A NACK shows as TX_ABRT and drops the sample
like a failed blocking read; the sample after a failure, and after any other access (status,
configure, read_raw: machine.I2C's, which first collect a read in flight), is a blocking one.

Units: 4096 counts per revolution. With the library's 51200 usteps per revolution one count is
12.5 usteps (0.0879 degrees), 8x coarser than the uStepper's TLE5012B (1.5625 usteps).
"""

from array import array

from ..micro import const, micropython, ptr32, ptr8
from ..motion.fixed import state_word
from ..motion.hal import MAGNET_MISSING, MAGNET_OK, MAGNET_STRONG, MAGNET_WEAK

ADDRESS = const(0x36)
CONF = const(0x07)
STATUS = const(0x0B)
RAW_ANGLE = const(0x0C)

COUNTS_PER_REV = const(4096)
_HALF = const(2048)
USTEPS_PER_COUNT = 51200 / 4096  # 12.5 exactly
DEGREES_PER_COUNT = 360.0 / 4096

# DW_apb_i2c registers as 32-bit word indices (RP2040 datasheet 4.3.17), and their bits.
_DATA_CMD = const(0x10 // 4)
_RAW_INTR_STAT = const(0x34 // 4)
_CLR_TX_ABRT = const(0x54 // 4)
_RXFLR = const(0x78 // 4)
_TX_ABRT_SOURCE = const(0x80 // 4)
_CMD_READ = const(0x100)
_CMD_STOP = const(0x200)
_TX_ABRT = const(0x40)
_SPINS = const(4000)  # polls of a read still on the wire (~0.2 us each): far beyond its 80 us

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


def magnet_health(status):
    """The STATUS byte as hal.py's MAGNET_* code (no tuple: the HOME task calls it)."""
    if not status & _MD:
        return MAGNET_MISSING
    if status & _ML:
        return MAGNET_WEAK
    if status & _MH:
        return MAGNET_STRONG
    return MAGNET_OK


def unwrap(prev, raw):
    """Signed count change from `prev` to `raw`, taking the shorter way round (|d| <= 2048)."""
    d = (raw - prev) & 0xFFF
    return d - COUNTS_PER_REV if d > _HALF else d


def counts_to_usteps(counts):
    """int(12.5 * counts), truncated toward zero like the library's int32 cast."""
    return int(counts * 12.5)


S_RAW = const(0)
S_COUNT = const(1)
S_ERRORS = const(2)
S_QUEUED = const(3)
S_AT = const(4)  # 2 words: the caller's tags of the sample last taken
S_NEXT = const(6)  # 2 words: the caller's tags of the read queued
_QUEUED = const(1)  # s[S_QUEUED]: what next_sample finds
_DROP = const(2)
_FRESH = const(3)
_FRESH_QUEUE = const(4)


class AS5600:
    """Reads one AS5600 through a machine.I2C-like object and keeps a multi-turn count.

    `count` is the angle since home in counts (int32); `sample()` reads once and returns
    False when the bus failed, leaving the count as it was (the library drops such a sample).
    The state is the int32 array `s` ([raw, count, errors, queued, tags of the sample (2), tags
    of the queued read (2)]) that the viper `next_sample` works on.
    """

    raw = state_word(S_RAW)
    count = state_word(S_COUNT)
    errors = state_word(S_ERRORS)
    queued = state_word(S_QUEUED)  # 1: a read of RAW ANGLE waits in the controller

    def __init__(self, i2c, address=ADDRESS, regs=0):
        self._i2c = i2c
        self._address = address
        self.regs = regs  # the controller's registers (an address on the chip), 0: blocking reads
        self.buf = bytearray(2)
        self._status = bytearray(1)
        self.s = array("i", bytes(4 * 8))
        self._at_raw = False  # the device's address pointer is at RAW ANGLE

    def configure(self, slow_filter, fast_threshold):
        """Write CONF (volatile; nothing is burnt) and read it back; OSError if it did not stick."""
        word = conf_word(slow_filter, fast_threshold)
        self._settle()
        buf = self.buf
        buf[0] = word >> 8
        buf[1] = word & 0xFF
        self._i2c.writeto_mem(self._address, CONF, buf)
        self._i2c.readfrom_mem_into(self._address, CONF, buf)
        got = ((buf[0] << 8) | buf[1]) & 0x3FFF
        if got != word:
            raise OSError("AS5600 CONF reads back 0x%04x, wrote 0x%04x" % (got, word))

    def _settle(self):
        """Let a queued read finish before machine.I2C touches the controller (its angle is
        dropped); the device's pointer will move."""
        s = self.s
        if s[S_QUEUED]:
            s[S_QUEUED] = _DROP
            next_sample(s, self.regs, self.buf, 0, 0)
        self._at_raw = False

    def status(self):
        self._settle()
        self._i2c.readfrom_mem_into(self._address, STATUS, self._status)
        return self._status[0]

    def read_raw(self):
        buf = self.buf
        self._settle()
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

    def sample(self, tag0=0, tag1=0):
        """One reading: the queued one (next_sample) or, when none is queued, a blocking read, after
        which the next read is queued when `regs` is set. `tag0`, `tag1`: the caller's words for
        this instant (tags of the sample it returns or, with a read queued, of that read)."""
        s = self.s
        got = next_sample(s, self.regs, self.buf, tag0, tag1)
        if got >= 0:
            return got == 1
        buf = self.buf
        try:
            if self._at_raw:
                self._i2c.readfrom_into(self._address, buf)
            else:
                self._i2c.readfrom_mem_into(self._address, RAW_ANGLE, buf)
                self._at_raw = True
        except OSError:
            self._at_raw = False
            s[S_ERRORS] += 1
            return False
        s[S_QUEUED] = _FRESH_QUEUE if self.regs else _FRESH
        return next_sample(s, self.regs, self.buf, tag0, tag1) == 1

    def usteps(self):
        return counts_to_usteps(self.count)

    def degrees(self):
        return self.count * DEGREES_PER_COUNT


@micropython.viper
def next_sample(s: ptr32, regs, buf: ptr8, tag0: int, tag1: int) -> int:
    """The 1 kHz sample, by s[S_QUEUED]: 0, no read queued: -1 (call AS5600.sample()); _QUEUED:
    the queued read's angle goes into s, its tags to s[S_AT], and the next read is queued with
    (tag0, tag1): 1, or 0 when the read failed (counted; nothing queued then). _DROP: wait for the
    queued read, keep nothing. _FRESH (_FRESH_QUEUE): a blocking read's bytes are in `buf`: taken
    with (tag0, tag1) (and the next read queued with them). One function, the register accesses
    inline: a call from viper costs ~6 us on the chip, and code costs heap."""
    mode = s[S_QUEUED]
    if mode == 0:
        return -1
    if mode == _QUEUED or mode == _DROP:
        r = ptr32(regs)
        spins = _SPINS
        while r[_RXFLR] < 2:
            spins -= 1
            if spins <= 0 or r[_RAW_INTR_STAT] & _TX_ABRT:
                spins = r[_TX_ABRT_SOURCE]  # read before the clear, as the pico-sdk does
                spins = r[_CLR_TX_ABRT]
                while r[_RXFLR] > 0:
                    spins = r[_DATA_CMD]
                s[S_QUEUED] = 0
                if mode == _QUEUED:
                    s[S_ERRORS] = s[S_ERRORS] + 1
                return 0
        buf[0] = r[_DATA_CMD] & 0xFF  # the emulator marks the first byte in bit 10
        buf[1] = r[_DATA_CMD] & 0xFF
        if mode == _DROP:
            s[S_QUEUED] = 0
            return 0
        s[S_AT] = s[S_NEXT]
        s[S_AT + 1] = s[S_NEXT + 1]
    else:
        s[S_AT] = tag0
        s[S_AT + 1] = tag1
    raw = ((buf[0] & 0x0F) << 8) | buf[1]
    d = (raw - s[S_RAW]) & 0xFFF
    s[S_COUNT] = s[S_COUNT] + (d - COUNTS_PER_REV if d > _HALF else d)  # mod 2**32 on any port
    s[S_RAW] = raw
    if mode == _FRESH:
        s[S_QUEUED] = 0
        return 1
    r = ptr32(regs)
    r[_DATA_CMD] = _CMD_READ  # the next read: START, address, 2 bytes, STOP
    r[_DATA_CMD] = _CMD_READ | _CMD_STOP
    s[S_NEXT] = tag0
    s[S_NEXT + 1] = tag1
    s[S_QUEUED] = _QUEUED
    return 1
