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
