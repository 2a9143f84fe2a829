"""The TMC5130 ramp generator of joint.sim.ramp in integers, one control tick at a time: the chip's.

A module of its own so that the board loads neither the float `Ramp` nor `math` (heap). The mode
constants are defined here and re-exported by joint.sim.ramp.
"""

from array import array

from ..micro import const, micropython, ptr32
from .fixed import state_word

POSITIONING = const(0)
VELOCITY_POS = const(1)
VELOCITY_NEG = const(2)
HOLD = const(3)

# TickRamp's state, one int32 each in `TickRamp.s` (the viper tick reads them as raw words; the
# Pico backend writes them directly on its frequent paths).
S_X = const(0)
S_XF = const(1)
S_V = const(2)
S_MODE = const(3)
S_XTARGET = const(4)
S_VMAX = const(5)
S_AMAX = const(6)
S_DMAX = const(7)


class TickRamp:
    """The same ramp generator in integers, advanced one control tick at a time (the chip's).

    Every float on the board is a heap object, so the 1 kHz path runs this instead of `Ramp`:

        r.vmax, r.amax, r.dmax   Q16 usteps per tick, per tick^2 (>= 0)
        r.mode, r.xtarget        as Ramp (xtarget int usteps)
        r.tick(), r.run(n)       advance one tick, n ticks
        r.x, r.xf, r.v           position: x usteps + xf / 65536; signed velocity, Q16 usteps/tick
        r.xactual(), r.set_position(n), r.position_reached()

    Positions advance by the trapezoid rule, so a constant acceleration is integrated exactly.
    Positioning brakes when the distance left is within the braking distance at DMAX, then
    decelerates at the rate that lands on the target (DMAX, give or take the tick's rounding).
    All arithmetic stays within small ints (Q16 speed < 2**27, the squares taken in Q8). The
    state is an int32 array `s` (indices S_X..S_DMAX) that one viper call advances: an attribute
    costs ~6 us on the chip, a word of the array a few instructions. Positions are int32 and
    wrap like the TMC5130's XACTUAL.
    """

    x = state_word(S_X)
    xf = state_word(S_XF)
    v = state_word(S_V)
    mode = state_word(S_MODE)
    xtarget = state_word(S_XTARGET)
    vmax = state_word(S_VMAX)
    amax = state_word(S_AMAX)
    dmax = state_word(S_DMAX)

    def __init__(self):
        self.s = array("i", bytes(4 * 8))  # mode POSITIONING (0), everything else 0

    def xactual(self):
        s = self.s
        return s[S_X] + 1 if s[S_XF] >= 0x8000 else s[S_X]

    def set_position(self, x):
        s = self.s
        s[S_X] = x
        s[S_XF] = 0

    def position_reached(self):
        s = self.s
        return (s[S_MODE] == POSITIONING and s[S_V] == 0 and s[S_X] == s[S_XTARGET]
                and s[S_XF] == 0)

    def tick(self):
        run_ramp(self.s, 1)

    def run(self, n):
        run_ramp(self.s, n)


@micropython.viper
def run_ramp(s: ptr32, n: int):
    """`n` ticks of the ramp whose state is `s`. Words are read through ((w + m) & k) - m, which
    sign-extends a 32-bit word on a 64-bit port (viper loads it zero-extended) and is the identity
    on the 32-bit chip and under CPython."""
    m = 1
    m <<= 31
    k = m + m - 1
    x = ((s[0] + m) & k) - m
    xf = ((s[1] + m) & k) - m
    v = ((s[2] + m) & k) - m
    mode = ((s[3] + m) & k) - m
    xtarget = ((s[4] + m) & k) - m
    vmax = ((s[5] + m) & k) - m
    amax = ((s[6] + m) & k) - m
    dmax = ((s[7] + m) & k) - m
    dm = dmax if dmax > 0 else 1
    i = 0
    while i < n:
        i += 1
        if mode == 0:  # POSITIONING
            d = xtarget - x
            if d == 0 and v == 0 and xf == 0:
                break
            sign = 1 if d > 0 or (d == 0 and v < 0) else -1
            u = v * sign
            dist = d * sign  # whole usteps toward the target
            land = 0
            if u < 0:
                un = u + dm  # moving away: brake, then come back
            else:
                u8 = u >> 8
                if u8 < 0x8000:
                    near = (u8 * u8) // (2 * dm) + (u >> 16) >= dist  # braking distance at dm
                else:
                    near = ((u8 >> 4) * (u8 >> 4)) // (2 * dm) + (u >> 24) >= dist >> 8
                if near:
                    if dist <= 0 or u <= 0:
                        land = 1
                    else:
                        if u8 < 0x8000:
                            a = (u8 * u8) // (2 * dist)
                        else:
                            den = dist >> 7
                            if den == 0:
                                den = 1
                            a = ((u8 >> 4) * (u8 >> 4)) // den
                        if a < 1:
                            a = 1
                        if u <= a or dist <= 1:
                            land = 1
                        un = u - a
                elif u > vmax:
                    un = u - dm
                    if un < vmax:
                        un = vmax
                else:
                    un = u + amax
                    if un > vmax:
                        un = vmax
                    if un == 0:
                        break  # vmax 0: parked short of the target
            if land:
                x = xtarget
                xf = 0
                v = 0
                break
            xf += sign * ((u + un) >> 1)
            x += xf >> 16
            xf &= 0xFFFF
            v = sign * un
        elif mode == 3:  # HOLD
            xf += v
            x += xf >> 16
            xf &= 0xFFFF
        else:
            vt = vmax if mode == 1 else -vmax  # VELOCITY_POS / VELOCITY_NEG
            if v < vt:
                vn = v + amax
                if vn > vt:
                    vn = vt
            else:
                vn = v - amax
                if vn < vt:
                    vn = vt
            xf += (v + vn) >> 1  # trapezoid rule, Q16 usteps
            x += xf >> 16
            xf &= 0xFFFF
            v = vn
    s[0] = x
    s[1] = xf
    s[2] = v
