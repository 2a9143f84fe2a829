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
exactly, so the result does not depend on how dt is sliced. The board runs its integer
twin, joint.motion.tickramp.TickRamp (this module is the simulator's: not loaded on the chip).
"""

import math

from ..motion.tickramp import HOLD, POSITIONING, VELOCITY_NEG, VELOCITY_POS

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
