"""Encoder velocity estimator of the uStepper library (ustepper-model.md section 3.2).

A PI tracking loop: a position estimate follows the measured position and the integrator is the
velocity. The library reports the integrator, not the loop's velocity term, so the output is the
true velocity through H(s) = ki / (s^2 + kp*s + ki): overdamped (poles -18.8 and -101.2 rad/s with
the defaults), unity DC gain, a*kp/ki = 63 ms lag under constant acceleration.

    est = VelocityEstimator(1541.85)     # call rate of update(), Hz
    est.update(position) -> velocity     # position in any unit (counts), velocity in unit/s
    est.reset(position=0.0)              # forget the velocity, track from `position`

Hardware-neutral: the simulated motor and the Pico backend feed it encoder counts at their
sampling rate.
"""

from .emitters import micropython


class VelocityEstimator:
    def __init__(self, rate_hz, kp=120.0, ki=1900.0):
        self._t = 1.0 / rate_hz
        self._kp = kp
        self._kit = ki * self._t
        self.value = 0.0
        self.reset()

    def reset(self, position=0.0):
        self._pos = float(position)
        self._vel = 0.0
        self.value = 0.0

    def update(self, position):
        self._pos += self._vel * self._t
        e = position - self._pos
        self.value += e * self._kit
        self._vel = e * self._kp + self.value
        return self.value


_E_LIMIT = 1 << 21  # Q12 counts: 512 counts of tracking error keep every product a small int


class FixedVelocityEstimator:
    """The same filter in integers (the chip's 1 kHz path: no float is created).

        est = FixedVelocityEstimator(1000)   # call rate of update(), integer Hz
        est.update(count)                   # integer encoder counts; returns counts/s in Q8
        est.value                           # counts/s x 256
        est.reset(count=0)

    The state is the tracking error (measured minus estimate, Q12 counts) rather than the estimate,
    so it stays small however far the joint turns. Gains are rounded once (ki / rate to 0.2 % at 1 kHz).
    """

    def __init__(self, rate_hz, kp=120.0, ki=1900.0):
        self._rate = int(rate_hz)
        # Q12 counts of error -> Q8 counts/s: x 2**-4, then the gain, kept scaled by 2**3 (kp) and
        # 2**12 (ki / rate) so the products stay below 2**30 within _E_LIMIT.
        self._kp = int(kp / 16 * 8 + 0.5)
        self._kit = int(ki / rate_hz / 16 * 4096 + 0.5)
        self.value = 0
        self.reset()

    def reset(self, count=0):
        self._last = count
        self._err = 0
        self._vel = 0
        self.value = 0

    @micropython.native
    def update(self, count):
        rate = self._rate
        vel = self._vel
        # Estimate advances by vel / rate counts: in Q12 that is vel(Q8) * 16 / rate, rounded.
        step = (vel * 16 + rate // 2) // rate if vel >= 0 else -((-vel * 16 + rate // 2) // rate)
        e = self._err + ((count - self._last) << 12) - step
        self._last = count
        if e > _E_LIMIT:
            e = _E_LIMIT
        elif e < -_E_LIMIT:
            e = -_E_LIMIT
        self._err = e
        value = self.value + ((e * self._kit) >> 12)
        self.value = value
        self._vel = ((e * self._kp) >> 3) + value
        return value
