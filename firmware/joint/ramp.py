"""TMC5130 ramp generator as the uStepper library configures it (ustepper-model.md section 5).

Hardware-neutral: the simulated motor integrates it to drive its virtual field, a step/dir backend
integrates it to time its pulses. Units are microsteps (usteps, 51200 per revolution) and seconds.

    r = Ramp()
    r.vmax, r.amax, r.dmax      # usteps/s, usteps/s^2 (>= 0), written like the driver registers
    r.mode = POSITIONING        # or VELOCITY_POS / VELOCITY_NEG (to +-vmax at amax) / HOLD
    r.xtarget = 51200           # int usteps, used in POSITIONING
    moved = r.step(dt)          # advance dt seconds; returns the distance travelled (usteps)
    r.x, r.v                    # position (float usteps), signed velocity (usteps/s)
    r.xactual()                 # XACTUAL, the integer position
    r.set_position(n)           # write XACTUAL: relabels x, keeps v (the field does not move)
    r.position_reached()

Positioning (V1=0, VSTART=0, the library's settings): a trapezoid, accelerating at amax up to vmax,
braking at dmax so that it lands on xtarget. A target behind the motion, or closer than the braking
distance, brakes at dmax, reverses and comes back. Lowering vmax below |v| decelerates at dmax. A
relabel (set_position) in positioning mode continues toward xtarget from the new x. Velocity modes
use amax for acceleration and deceleration alike; HOLD keeps v. step() integrates each ramp segment
exactly, so the result does not depend on how dt is sliced.
"""

from .emitters import micropython, ptr32

import math
from array import array

try:
    from micropython import const
except ImportError:
    def const(x):
        return x

POSITIONING = const(0)
VELOCITY_POS = const(1)
VELOCITY_NEG = const(2)
HOLD = const(3)

_BRAKE_EARLY = 1e-3  # usteps: rounding slack when deciding that the braking point is reached
_LAND_SLACK = 1.0  # usteps: a brake ending this far past the target still lands on it (VSTOP)
_MIN_RATE = 1e-9  # usteps/s^2: stands in for a zero AMAX/DMAX register (no speed change)


class Ramp:
    def __init__(self):
        self.x = 0.0
        self.v = 0.0
        self.mode = POSITIONING
        self.xtarget = 0
        self.vmax = 0.0
        self.amax = 0.0
        self.dmax = 0.0

    def xactual(self):
        return math.floor(self.x + 0.5)

    def set_position(self, x):
        self.x = float(x)

    def position_reached(self):
        return self.mode == POSITIONING and self.v == 0.0 and self.x == self.xtarget

    def step(self, dt):
        x0 = x = self.x
        v = self.v
        for _ in range(8):  # a call spans at most a few segments; the cap guards rounding loops
            if dt <= 0.0:
                break
            mode = self.mode
            if mode == POSITIONING:
                d = self.xtarget - x
                if d == 0.0 and v == 0.0:
                    break
                s = 1.0 if d > 0.0 or (d == 0.0 and v < 0.0) else -1.0
                # Work in "toward the target" coordinates: u speed, dist remaining (>= 0).
                u = v * s
                dist = d * s
                dm = self.dmax if self.dmax > _MIN_RATE else _MIN_RATE
                vmax = self.vmax
                if u < 0.0:
                    a, uend = dm, 0.0  # moving away: brake, then come back
                else:
                    brake = u * u / (2.0 * dm)
                    if brake >= dist - _BRAKE_EARLY:
                        if brake > dist + _LAND_SLACK:
                            a, uend = -dm, 0.0  # too close to stop: overshoot and reverse
                        else:
                            if u * dt >= 2.0 * dist or dist <= _BRAKE_EARLY:
                                if u > 0.0:
                                    dt -= 2.0 * dist / u
                                x = float(self.xtarget)
                                v = 0.0
                                continue
                            a = -u * u / (2.0 * dist)
                            x += s * (u + 0.5 * a * dt) * dt
                            v = s * (u + a * dt)
                            break
                    elif u > vmax:
                        a, uend = -dm, vmax
                    elif u < vmax:
                        am = self.amax if self.amax > _MIN_RATE else _MIN_RATE
                        peak = math.sqrt((dist + u * u / (2.0 * am)) / (0.5 / dm + 0.5 / am))
                        a, uend = am, (peak if peak < vmax else vmax)
                    else:
                        if u == 0.0:
                            break  # vmax 0: parked short of the target
                        t = (dist - brake) / u
                        if t >= dt:
                            x += s * u * dt
                            break
                        x += s * u * t
                        dt -= t
                        continue
                t = (uend - u) / a
                if t >= dt:
                    x += s * (u + 0.5 * a * dt) * dt
                    v = s * (u + a * dt)
                    break
                x += s * 0.5 * (u + uend) * t
                v = s * uend
                dt -= t
            elif mode == HOLD:
                x += v * dt
                break
            else:
                vt = self.vmax if mode == VELOCITY_POS else -self.vmax
                dv = vt - v
                if dv == 0.0:
                    x += v * dt
                    break
                am = self.amax if self.amax > _MIN_RATE else _MIN_RATE
                a = am if dv > 0.0 else -am
                t = dv / a
                if t >= dt:
                    x += (v + 0.5 * a * dt) * dt
                    v += a * dt
                    break
                x += 0.5 * (v + vt) * t
                v = vt
                dt -= t
        else:
            x += v * dt
        self.x = x
        self.v = v
        return x - x0


# TickRamp's state, one int32 each in `TickRamp.s` (the viper tick reads them as raw words).
_X = const(0)
_XF = const(1)
_V = const(2)
_MODE = const(3)
_XTARGET = const(4)
_VMAX = const(5)
_AMAX = const(6)
_DMAX = const(7)


def _field(i):
    def get(self):
        return self.s[i]

    def put(self, value):
        self.s[i] = value
    return property(get, put)


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
    state is an int32 array `s` (indices _X.._DMAX) that one viper call advances: an attribute
    costs ~6 us on the chip, a word of the array a few instructions. Positions are int32 and
    wrap like the TMC5130's XACTUAL.
    """

    x = _field(_X)
    xf = _field(_XF)
    v = _field(_V)
    mode = _field(_MODE)
    xtarget = _field(_XTARGET)
    vmax = _field(_VMAX)
    amax = _field(_AMAX)
    dmax = _field(_DMAX)

    def __init__(self):
        self.s = array("i", bytes(4 * 8))  # mode POSITIONING (0), everything else 0

    def xactual(self):
        s = self.s
        return s[_X] + 1 if s[_XF] >= 0x8000 else s[_X]

    def set_position(self, x):
        s = self.s
        s[_X] = x
        s[_XF] = 0

    def position_reached(self):
        s = self.s
        return (s[_MODE] == POSITIONING and s[_V] == 0 and s[_X] == s[_XTARGET]
                and s[_XF] == 0)

    def tick(self):
        _run(self.s, 1)

    def run(self, n):
        _run(self.s, n)


@micropython.viper
def _run(s: ptr32, n: int):
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
