"""TMC2209 over its single-wire UART: datagrams, register fields and current scaling.

Datagrams (TMC2209 datasheet rev 1.03, section 4), every byte sent LSB first, MSB byte first:

    write   05 | node 0..3 | reg|0x80 | data[31:24] .. data[7:0] | CRC      (8 bytes)
    request 05 | node 0..3 | reg      | CRC                                (4 bytes)
    reply   05 | FF        | reg      | data[31:24] .. data[7:0] | CRC      (8 bytes)

CRC: CRC-8 with polynomial x^8+x^2+x+1, initial value 0, bits fed LSB first (section 4.2).
PDN_UART is one wire: the Pico's TX reaches it through 1 kOhm and RX listens directly, so RX
hears every byte we send (the echo) before the driver's reply. The driver answers only reads and
counts each valid write in IFCNT, which is how writes are verified. The values written once at
boot (CHOPCONF, TPOWERDOWN, TPWMTHRS, the current scale) come from tmc2209_setup.py.
"""

from ..micro import const

SYNC = const(0x05)
MASTER = const(0xFF)
WRITE = const(0x80)

GCONF = const(0x00)
GSTAT = const(0x01)
IFCNT = const(0x02)
IOIN = const(0x06)
IHOLD_IRUN = const(0x10)
TPOWERDOWN = const(0x11)
TPWMTHRS = const(0x13)
CHOPCONF = const(0x6C)
DRV_STATUS = const(0x6F)
PWMCONF = const(0x70)

VERSION = const(0x21)  # IOIN[31:24] of a TMC2209

# GCONF bits
I_SCALE_ANALOG = const(1 << 0)
EN_SPREADCYCLE = const(1 << 2)
SHAFT = const(1 << 3)
PDN_DISABLE = const(1 << 6)  # the PDN_UART pin serves the UART only
MSTEP_REG_SELECT = const(1 << 7)  # microsteps from CHOPCONF.MRES, not from the MS1/MS2 pins
MULTISTEP_FILT = const(1 << 8)

# PWMCONF.freewheel (bits 21:20): what the coils do at standstill when IHOLD = 0 (StealthChop only)
FREEWHEEL_NORMAL = const(0)
FREEWHEEL_OPEN = const(1)
FREEWHEEL_SHORT_LS = const(2)
_FREEWHEEL_SHIFT = const(20)
_FREEWHEEL_MASK = const(3 << 20)

# Brake modes of the uStepper library (setBrakeMode)
BRAKE_FREEWHEEL = const(0)
BRAKE_COOL = const(1)
BRAKE_HARD = const(2)
BRAKE_HARD_PERCENT = 25  # the library's default brakeCurrent


class TMCError(OSError):
    """The driver did not answer, or answered with a corrupt or unexpected datagram."""


def crc8(buf, n, start=0):
    """CRC of buf[start:start + n], as the TMC22xx computes it."""
    crc = 0
    for i in range(start, start + n):
        byte = buf[i]
        for _ in range(8):
            if (crc >> 7) ^ (byte & 1):
                crc = ((crc << 1) ^ 0x07) & 0xFF
            else:
                crc = (crc << 1) & 0xFF
            byte >>= 1
    return crc


def pack_write(buf, node, reg, value):
    """Fill buf[0:8] with the write datagram setting `reg` to the 32-bit `value`."""
    buf[0] = SYNC
    buf[1] = node
    buf[2] = (reg & 0x7F) | WRITE
    buf[3] = (value >> 24) & 0xFF
    buf[4] = (value >> 16) & 0xFF
    buf[5] = (value >> 8) & 0xFF
    buf[6] = value & 0xFF
    buf[7] = crc8(buf, 7)


def pack_read(buf, node, reg):
    """Fill buf[0:4] with the read request for `reg`."""
    buf[0] = SYNC
    buf[1] = node
    buf[2] = reg & 0x7F
    buf[3] = crc8(buf, 3)


def parse_reply(buf, offset, reg):
    """Value of the 8-byte reply at buf[offset:]; TMCError if it is not a valid reply for `reg`."""
    if buf[offset] & 0x0F != SYNC:
        raise TMCError("TMC2209 reply: bad sync byte 0x%02x" % buf[offset])
    if buf[offset + 1] != MASTER:
        raise TMCError("TMC2209 reply: address 0x%02x, expected 0xff" % buf[offset + 1])
    if buf[offset + 2] != reg:
        raise TMCError("TMC2209 reply: register 0x%02x, expected 0x%02x" % (buf[offset + 2], reg))
    crc = crc8(buf, 7, offset)
    if crc != buf[offset + 7]:
        raise TMCError("TMC2209 reply: CRC 0x%02x, computed 0x%02x" % (buf[offset + 7], crc))
    return (buf[offset + 3] << 24) | (buf[offset + 4] << 16) | (buf[offset + 5] << 8) | buf[offset + 6]


def gconf(shaft=False):
    """GCONF for UART operation: internal current reference (VREF ignored), external sense
    resistors, StealthChop enabled (switching to SpreadCycle above TPWMTHRS), MRES from the
    register, PDN_UART used as UART only, step filtering on (its reset value)."""
    return PDN_DISABLE | MSTEP_REG_SELECT | MULTISTEP_FILT | (SHAFT if shaft else 0)


def ihold_irun(ihold, irun, iholddelay=0):
    return (ihold & 0x1F) | ((irun & 0x1F) << 8) | ((iholddelay & 0xF) << 16)


def pwmconf(base, freewheel):
    return (base & ~_FREEWHEEL_MASK) | ((freewheel & 3) << _FREEWHEEL_SHIFT)


def percent_to_cs(percent, cs_max):
    """The uStepper library's IRUN = ceil(0.31 * percent) (0..100 %, else 16), with 31 replaced
    by `cs_max` so that 100 % is the configured full scale. 0 % still leaves 1/32 (CS=0)."""
    if not 0 <= percent <= 100:
        return (16 * cs_max + 15) // 31
    t = percent * cs_max
    cs = int(t // 100)
    if cs * 100 < t:
        cs += 1
    return cs


def brake_settings(mode, cs_max):
    """(IHOLD, freewheel) for a brake mode: freewheel opens the coils and coolbrake shorts them
    through the low-side FETs, both by IHOLD = 0 at standstill; hardbrake holds with 25 %.
    Any other mode holds too: a bad value must not let the joint fall."""
    if mode == BRAKE_FREEWHEEL:
        return 0, FREEWHEEL_OPEN
    if mode == BRAKE_COOL:
        return 0, FREEWHEEL_SHORT_LS
    return percent_to_cs(BRAKE_HARD_PERCENT, cs_max), FREEWHEEL_NORMAL


def decode_drv_status(value):
    """DRV_STATUS (0x6F) as a dict of flags plus the actual current scale."""
    return {
        "otpw": bool(value & 1),  # over-temperature pre-warning
        "ot": bool(value & 2),  # over-temperature shutdown
        "s2ga": bool(value & 4),  # short to ground, phase A / B
        "s2gb": bool(value & 8),
        "s2vsa": bool(value & 16),  # low-side short, phase A / B
        "s2vsb": bool(value & 32),
        "ola": bool(value & 64),  # open load, phase A / B (valid only in slow motion)
        "olb": bool(value & 128),
        "t120": bool(value & (1 << 8)),
        "t143": bool(value & (1 << 9)),
        "t150": bool(value & (1 << 10)),
        "t157": bool(value & (1 << 11)),
        "cs_actual": (value >> 16) & 0x1F,
        "stealth": bool(value & (1 << 30)),
        "stst": bool(value & (1 << 31)),
    }


class TMC2209:
    """Register access to one TMC2209 on a UART-like object (write, readinto, any).

    Every call blocks until the echo (and for reads the reply) has arrived, about 0.7 ms per
    write and 1.1 ms per read at 115200 baud; the UART's timeout bounds the wait.
    """

    def __init__(self, uart, node=0):
        self._uart = uart
        self.node = node
        self._tx = bytearray(8)
        self._txv = memoryview(self._tx)
        self._rx = bytearray(12)
        self._rxv = memoryview(self._rx)

    def _drain(self):
        uart = self._uart
        n = uart.any()
        while n:
            uart.readinto(self._rxv[:min(n, 12)])
            n = uart.any()

    def _echo(self, n):
        got = self._uart.readinto(self._rxv[:n]) or 0
        if got == n:
            for i in range(n):
                if self._rx[i] != self._tx[i]:
                    break
            else:
                return
        raise TMCError("TMC2209 UART: no clean echo of our %d bytes (got %d); check that RX "
                           "is wired to PDN_UART and TX through 1 kOhm" % (n, got))

    def write(self, reg, value):
        self._drain()
        pack_write(self._tx, self.node, reg, value)
        self._uart.write(self._tx)
        self._echo(8)

    def read(self, reg):
        self._drain()
        pack_read(self._tx, self.node, reg)
        self._uart.write(self._txv[:4])
        self._echo(4)
        got = self._uart.readinto(self._rxv[4:12]) or 0
        if got != 8:
            raise TMCError("TMC2209 at node %d: no reply to a read of register 0x%02x (%d of 8 bytes)"
                           % (self.node, reg, got))
        return parse_reply(self._rx, 4, reg)
