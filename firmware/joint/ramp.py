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

from .emitters import micropython

import math

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


class TickRamp:
    """The same ramp generator in integers, advanced one control tick at a time (the chip's).

    Every float on the board is a heap object, so the 1 kHz path runs this instead of `Ramp`:

        r.vmax, r.amax, r.dmax   Q16 usteps per tick, per tick^2 (>= 0)
        r.mode, r.xtarget        as Ramp (xtarget int usteps)
        r.tick()                 advance one tick
        r.x, r.xf, r.v           position: x usteps + xf / 65536; signed velocity, Q16 usteps/tick
        r.xactual(), r.set_position(n), r.position_reached()

    Positions advance by the trapezoid rule, so a constant acceleration is integrated exactly.
    Positioning brakes when the distance left is within the braking distance at DMAX, then
    decelerates at the rate that lands on the target (DMAX, give or take the tick's rounding).
    All arithmetic stays within small ints (Q16 speed < 2**27, the squares taken in Q8).
    """

    def __init__(self):
        self.x = 0
        self.xf = 0
        self.v = 0
        self.mode = POSITIONING
        self.xtarget = 0
        self.vmax = 0
        self.amax = 0
        self.dmax = 0

    def xactual(self):
        return self.x + 1 if self.xf >= 0x8000 else self.x

    def set_position(self, x):
        self.x = x
        self.xf = 0

    def position_reached(self):
        return self.mode == POSITIONING and self.v == 0 and self.x == self.xtarget and self.xf == 0

    @micropython.native
    def tick(self):
        v = self.v
        mode = self.mode
        if mode == POSITIONING:
            d = self.xtarget - self.x
            if d == 0 and v == 0 and self.xf == 0:
                return
            s = 1 if d > 0 or (d == 0 and v < 0) else -1
            u = v * s
            dist = d * s  # whole usteps toward the target
            dm = self.dmax if self.dmax > 0 else 1
            if u < 0:
                un = u + dm  # moving away: brake, then come back
            else:
                u8 = u >> 8
                if u8 < 0x8000:
                    brake = (u8 * u8) // (2 * dm)  # usteps to stop at dm
                    near = brake + (u >> 16) >= dist
                else:
                    near = ((u8 >> 4) * (u8 >> 4)) // (2 * dm) + (u >> 24) >= dist >> 8
                if near:
                    if dist <= 0 or u <= 0:
                        self._land()
                        return
                    if u8 < 0x8000:
                        a = (u8 * u8) // (2 * dist)
                    else:
                        a = ((u8 >> 4) * (u8 >> 4)) // ((dist >> 7) or 1)
                    if a < 1:
                        a = 1
                    if u <= a or dist <= 1:
                        self._land()
                        return
                    un = u - a
                elif u > self.vmax:
                    un = u - dm
                    if un < self.vmax:
                        un = self.vmax
                else:
                    un = u + self.amax
                    if un > self.vmax:
                        un = self.vmax
                    if un == 0:
                        return  # vmax 0: parked short of the target
            xf = self.xf + s * ((u + un) >> 1)
            self.x += xf >> 16
            self.xf = xf & 0xFFFF
            self.v = s * un
        elif mode == HOLD:
            xf = self.xf + v
            self.x += xf >> 16
            self.xf = xf & 0xFFFF
        else:
            vt = self.vmax if mode == VELOCITY_POS else -self.vmax
            am = self.amax
            if v < vt:
                vn = v + am
                if vn > vt:
                    vn = vt
            else:
                vn = v - am
                if vn < vt:
                    vn = vt
            xf = self.xf + ((v + vn) >> 1)  # trapezoid rule, Q16 usteps
            self.x += xf >> 16
            self.xf = xf & 0xFFFF
            self.v = vn

    def _land(self):
        self.x = self.xtarget
        self.xf = 0
        self.v = 0
