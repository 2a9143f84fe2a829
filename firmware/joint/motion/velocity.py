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

from array import array

from ..micro import const, micropython, ptr32


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


_E_LIMIT = const(1 << 21)  # Q12 counts: 512 counts of tracking error keep every product a small int


class FixedVelocityEstimator:
    """The same filter in integers (the chip's 1 kHz path: no float is created).

        est = FixedVelocityEstimator(1000)   # call rate of update(), integer Hz
        est.update(count)                   # integer encoder counts; returns counts/s in Q8
        est.value                           # counts/s x 256
        est.reset(count=0)

    The state is the tracking error (measured minus estimate, Q12 counts) rather than the estimate,
    so it stays small however far the joint turns. Gains are rounded once (ki / rate to 0.2 % at 1 kHz).
    State and gains are the int32 array `s` ([rate, kp, kit, last count, error, vel, value, error
    bound]) that one viper call updates (attributes cost ~6 us each on the chip).
    """

    def __init__(self, rate_hz, kp=120.0, ki=1900.0):
        # Q12 counts of error -> Q8 counts/s: x 2**-4, then the gain, kept scaled by 2**3 (kp) and
        # 2**12 (ki / rate) so the products stay below 2**30 within _E_LIMIT.
        kit = int(ki / rate_hz / 16 * 4096 + 0.5)
        # The error bound keeps e * kit within 2**30 (viper works in 32-bit words): _E_LIMIT at
        # 1 kHz, lower at slower loop rates, whose larger kit would overflow it.
        limit = (1 << 30) // kit if kit > 0 else _E_LIMIT
        self.s = array("i", (int(rate_hz), int(kp / 16 * 8 + 0.5), kit, 0, 0, 0, 0,
                             limit if limit < _E_LIMIT else _E_LIMIT))

    @property
    def value(self):
        return self.s[6]

    def reset(self, count=0):
        s = self.s
        s[3] = count
        s[4] = s[5] = s[6] = 0

    def update(self, count):
        return update_velocity(self.s, count)


@micropython.viper
def update_velocity(s: ptr32, count: int) -> int:
    """One estimator step over the state `s` (see FixedVelocityEstimator); words are read
    sign-extended as in tickramp.run_ramp."""
    m = 1
    m <<= 31
    k = m + m - 1
    rate = ((s[0] + m) & k) - m
    vel = ((s[5] + m) & k) - m
    # Estimate advances by vel / rate counts: in Q12 that is vel(Q8) * 16 / rate, rounded.
    half = rate >> 1
    step = (vel * 16 + half) // rate if vel >= 0 else 0 - ((0 - vel * 16 + half) // rate)
    e = ((s[4] + m) & k) - m + ((count - (((s[3] + m) & k) - m)) << 12) - step
    s[3] = count
    limit = ((s[7] + m) & k) - m
    if e > limit:
        e = limit
    elif e < 0 - limit:
        e = 0 - limit
    s[4] = e
    value = ((s[6] + m) & k) - m + ((e * (((s[2] + m) & k) - m)) >> 12)
    s[6] = value
    s[5] = ((e * (((s[1] + m) & k) - m)) >> 3) + value
    return value
