"""TMC5130A over SPI: 40-bit datagrams, the registers the joint uses and their units.

Datagram (TMC5130A datasheet section 4.1, SPI mode 3, MSB first, chip select low for the frame):

    sent      addr (bit 7 = write) | data[31:24] | data[23:16] | data[15:8] | data[7:0]
    received  SPI_STATUS           | data of the PREVIOUS read request (32 bits)

A read therefore takes two frames: the first names the register, the second brings its value.
SPI_STATUS bits: 0 reset_flag, 1 driver_error, 2 sg2, 3 standstill, 4 velocity_reached,
5 position_reached, 6 status_stop_l, 7 status_stop_r.

Units with the S32's 10 MHz clock (ustepper-model.md section 2): VMAX and VACTUAL in
2**24 / fCLK usteps per s per count (0.596046 usteps/s), AMAX and DMAX in 2**41 / fCLK**2 usteps/s^2
per count (45.4747 usteps/s^2); XACTUAL and XTARGET in usteps (256 per full step).
Register values are handled as signed 30-bit ints (wrapping at 2**30 like the HAL's positions),
so reading and writing allocate nothing.
"""

from ..micro import const

WRITE = const(0x80)
GCONF = const(0x00)
GSTAT = const(0x01)
IOIN = const(0x04)
IHOLD_IRUN = const(0x10)
TPOWERDOWN = const(0x11)
TPWMTHRS = const(0x13)
RAMPMODE = const(0x20)
XACTUAL = const(0x21)
VACTUAL = const(0x22)
VSTART = const(0x23)
A1 = const(0x24)
V1 = const(0x25)
AMAX = const(0x26)
VMAX = const(0x27)
DMAX = const(0x28)
D1 = const(0x2A)
VSTOP = const(0x2B)
XTARGET = const(0x2D)
RAMP_STAT = const(0x35)
CHOPCONF = const(0x6C)
DRV_STATUS = const(0x6F)
PWMCONF = const(0x70)

VERSION = const(0x11)  # IOIN[31:24] of a TMC5130

# RAMPMODE
POSITIONING = const(0)
VELOCITY_POS = const(1)
VELOCITY_NEG = const(2)

# SPI_STATUS
STANDSTILL = const(0x08)
POSITION_REACHED = const(0x20)

# GCONF: current reference from AIN (the S32's setting), StealthChop on, shaft reversal.
GCONF_BASE = const(0x05)
SHAFT = const(0x10)
# CHOPCONF as the uStepper library writes it: TOFF 2, HSTRT 4, HEND 0, TBL 2, MRES 0 (256 usteps).
CHOPCONF_BASE = const(0x00010042)
# PWMCONF: PWM_AMPL 128, PWM_GRAD 1, PWM_FREQ 0, autoscale; FREEWHEEL in bits 21:20.
PWMCONF_BASE = const(0x00040180)
FREEWHEEL_SHIFT = const(20)

VMAX_LIMIT = const(0x7FFE00)
AMAX_LIMIT = const(0xFFFE)
VSTOP_MIN = const(10)  # the datasheet's minimum for positioning mode

_WRAP = const(0x3FFFFFFF)
_SIGN = const(0x20000000)


class TMCError(OSError):
    """The TMC5130 did not answer as one does (no chip, no power, wrong bus)."""


class TMC5130:
    """Register access over a machine.SPI (mode 3) and a chip-select Pin (low = selected)."""

    def __init__(self, spi, cs):
        self._spi = spi
        self._cs = cs
        self._tx = bytearray(5)
        self.rx = bytearray(5)  # the last frame received (diagnostics decode its bytes)
        self.status = 0
        cs(1)

    def frame(self, addr, value):
        """One datagram; returns the 32 bits it brought back (the previous read request's
        register) as a signed 30-bit int."""
        tx = self._tx
        rx = self.rx
        tx[0] = addr
        tx[1] = (value >> 24) & 0xFF
        tx[2] = (value >> 16) & 0xFF
        tx[3] = (value >> 8) & 0xFF
        tx[4] = value & 0xFF
        self._cs(0)
        self._spi.write_readinto(tx, rx)
        self._cs(1)
        self.status = rx[0]
        x = ((rx[1] & 0x3F) << 24) | (rx[2] << 16) | (rx[3] << 8) | rx[4]
        return x - _WRAP - 1 if x & _SIGN else x

    def write(self, reg, value):
        self.frame(reg | WRITE, value)

    def read(self, reg):
        self.frame(reg, 0)
        return self.frame(reg, 0)

    def check(self):
        """Raise TMCError unless IOIN reports a TMC5130 (a missing chip reads 0x00 or 0xFF)."""
        self.read(IOIN)
        if self.rx[1] != VERSION:
            raise TMCError("no TMC5130 on SPI: IOIN version 0x%02x, expected 0x%02x" % (self.rx[1], VERSION))


def signed24(value):
    """VACTUAL's 24-bit two's complement as an int."""
    value &= 0xFFFFFF
    return value - 0x1000000 if value & 0x800000 else value


def ihold_irun(ihold, irun, delay=6):
    return (ihold & 31) | ((irun & 31) << 8) | ((delay & 15) << 16)


def percent_to_cs(percent):
    """Current scale 0..31 of `percent` of full scale, as the library's setCurrent (x 0.31, cut)."""
    percent = 0 if percent < 0 else (100 if percent > 100 else percent)
    return int(percent) * 31 // 100


def vmax_of_fs_q4(fs_q4):
    """VMAX of a speed in full steps/s, Q4: x 256 x 2**24 / 10 MHz / 16 = x 26.8435 (53687/2000)."""
    q = fs_q4 // 2000
    v = q * 53687 + (fs_q4 - q * 2000) * 53687 // 2000
    return v if v < VMAX_LIMIT else VMAX_LIMIT


def amax_of_fs_q4(fs_q4):
    """AMAX of an acceleration in full steps/s^2, Q4: x 256 x 2**41 / (10 MHz)**2 / 16 = x 0.35184."""
    q = fs_q4 // 6250
    a = q * 2199 + (fs_q4 - q * 6250) * 2199 // 6250
    return a if a < AMAX_LIMIT else AMAX_LIMIT


def vmax_of_rpm_q16(rpm_q16):
    """VMAX of a speed in rpm, Q16 (sign ignored): rpm x 51200 / 60 x 2**24 / 10 MHz / 65536 = / 45.776."""
    a = rpm_q16 if rpm_q16 >= 0 else -rpm_q16
    q = a // 45776
    v = q * 1000 + (a - q * 45776) * 1000 // 45776
    return v if v < VMAX_LIMIT else VMAX_LIMIT


def rpm_q16_of_vactual(vactual):
    """rpm in Q16 of a VACTUAL (usteps x 0.596046 / s): x 45.776, rounded toward minus infinity."""
    q = vactual // 1000
    return q * 45776 + (vactual - q * 1000) * 45776 // 1000
