"""TMC2209 configuration values computed once, at boot (startup.BOOT_ONLY): the board forgets this
module once the driver is configured.

Coil current (datasheet, motor current setting), with the internal reference (I_scale_analog=0):

    I_rms = (CS + 1) / 32 * V_fs / (R_sense + 0.02 Ohm) / sqrt(2)

V_fs = 0.325 V (vsense=0) or 0.180 V (vsense=1), CS = IRUN or IHOLD (0..31). The datasheet's
sense-resistor table (e.g. 0.10 Ohm, CS=31, vsense=0 -> 1.92 A) matches this formula.
"""

from ..micro import const

# CHOPCONF fields
_TOFF_MASK = const(0xF)
_DEFAULT_TOFF = const(3)
_VSENSE = const(1 << 17)
_MRES_SHIFT = const(24)
_MRES_MASK = const(0xF << 24)
_INTPOL = const(1 << 28)

FCLK = 12000000  # Hz, internal oscillator (typical; the datasheet allows a few % spread)

V_FS = (0.325, 0.180)  # full-scale sense voltage for vsense = 0, 1
R_INTERNAL = 0.02  # Ohm the datasheet adds to R_sense
_SQRT2 = 1.4142135623730951


def mres(microsteps):
    """CHOPCONF.MRES for 256, 128, .., 2, 1 (full step) microsteps per full step."""
    code = 0
    m = 256
    while m > microsteps:
        m >>= 1
        code += 1
    if m != microsteps or microsteps < 1:
        raise ValueError("microsteps must be a power of two in 1..256, got %r" % (microsteps,))
    return code


def chopconf(base, microsteps, vsense):
    """CHOPCONF from the value read at power-up: keep its (OTP-tuned) chopper timing, set MRES,
    vsense and interpolation. TOFF=0 would disable the bridges, so it gets the reset value 3."""
    value = base & ~(_MRES_MASK | _VSENSE | _INTPOL)
    if value & _TOFF_MASK == 0:
        value |= _DEFAULT_TOFF
    value |= (mres(microsteps) << _MRES_SHIFT) | _INTPOL
    if vsense:
        value |= _VSENSE
    return value


def tpowerdown(seconds):
    """TPOWERDOWN: delay from standstill detection (2^20 clocks) to hold current, 2^18 clocks a unit."""
    return max(0, min(255, int(seconds * FCLK / 262144 + 0.5)))


def tpwmthrs(usteps_per_s):
    """TPWMTHRS: StealthChop below this speed, SpreadCycle above. TSTEP, which it is compared
    with, counts clocks per 1/256 microstep whatever MRES is (datasheet: TSTEP register)."""
    return max(0, min(0xFFFFF, int(FCLK / usteps_per_s)))


def rms_current(cs, vsense, rsense):
    """Coil RMS current in A for current scale cs (0..31)."""
    return (cs + 1) / 32.0 * V_FS[vsense] / (rsense + R_INTERNAL) / _SQRT2


def current_scale(rsense, full_scale_a):
    """(vsense, cs_max): the largest CS whose current does not exceed `full_scale_a`.

    vsense=1 (lower sense voltage) is used whenever it reaches the full scale, because it gives
    a larger CS for the same current (finer steps, less loss in R_sense); the datasheet
    recommends CS >= 16 for good microstep accuracy. ValueError if unreachable either way.
    """
    for vsense in (1, 0):
        cs = int(full_scale_a * 32.0 * _SQRT2 * (rsense + R_INTERNAL) / V_FS[vsense] + 1e-9) - 1
        if cs > 31:
            continue
        if cs < 0:
            break
        return vsense, cs
    raise ValueError("%.3f A RMS is outside %.3f..%.3f A for R_sense %.3f Ohm"
                     % (full_scale_a, rms_current(0, 1, rsense), rms_current(31, 0, rsense), rsense))
