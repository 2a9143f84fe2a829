"""Simulated uStepper S32: TMC5130 ramp generator, stepper rotor, TLE5012B encoder and the library's
1541.85 Hz ISR (encoder sample, velocity estimator, closed-loop re-synchronisation), behind MotorHAL.

Behaviour follows reference/ustepper-model.md sections 2-5 and 8: the "PID error" is the driver
position minus the encoder position, the closed loop only relabels XACTUAL (the field keeps turning),
so a blocked rotor shows a bounded error with pole-slip spikes, never a growing one.

Physics (Level 2 of section 8.4, integrated cheaply): the rotor is an inertia pulled toward the
field by T_max*sin(2*pi*(F - R)/1024) (50 pole pairs), T_max = T_hold*(I+1)/32 rolled off by back-EMF,
minus viscous, Coulomb (with stiction) and external load torque. Semi-implicit Euler sub-steps are
laid on the ISR grid, as many per ISR period as the slip speed and the electrical stiffness need
(one or two in synchronous running, more while slipping or touching a wall), and none while
everything rests. Walls are one-sided springs with damping, sub-stepped finely while touched.

Frames: R (rotor) and F (field) are mechanical usteps in the physical frame, 0 = rotor angle at
construction; the field advances by wiring_sign * (shaft ? -1 : 1) per driver ustep. The encoder
counts grow with R (the connector/magnet orientation is folded into wiring_sign).

Simulator hooks (not part of MotorHAL):
    rotor_angle()                  true rotor angle, motor degrees (0 = at construction)
    set_end_stops(low_deg=None, high_deg=None)   one-sided walls in that frame (None: no wall)
    add_obstacle(angle_deg, direction)           a wall at angle_deg blocking motion in direction +1/-1
    clear_obstacles()              remove the obstacles (end stops stay)
    block()                        a wall where the rotor is now, against its direction of motion
                                   (rotor speed, else the field's; +1 when both rest)
    set_load_torque(nm)            constant external torque; positive pushes toward negative angles
    driver_position()              XACTUAL, usteps
Walls belong on the side the rotor is not on: one placed behind the rotor pushes it out like a
compressed spring. The default stiffness is a rigid stop on the motor shaft; a collision of the arm
seen through the joint reduction N is far softer (joint stiffness / N^2).

Before begin() the driver is unconfigured: coils off, ISR not running. stop() does not busy-wait as
the library does: it starts the deceleration and update() completes it. driver_rpm() reports the
true ramp speed, not the library's 0.596x figure.
"""

import math

from ..hal import MotorHAL
from ..ramp import Ramp, POSITIONING, VELOCITY_POS, VELOCITY_NEG
from ..velocity import VelocityEstimator

_F_ISR = 1541.85
_T_ISR = 1.0 / _F_ISR
_T_ISR_US = 1e6 / _F_ISR
_USTEPS_PER_REV = 51200.0
_COUNTS_PER_REV = 32768.0
_COUNTS_PER_USTEP = _COUNTS_PER_REV / _USTEPS_PER_REV
_ANGLE_TO_STEP = 51200.0 / 360.0
_KE = 2.0 * math.pi / 1024.0  # electrical radians per ustep (one period = 4 full steps)
_RAD_PER_USTEP = 2.0 * math.pi / _USTEPS_PER_REV
# TMC5130 at fCLK = 10 MHz: register units to usteps/s and usteps/s^2.
_VREG = 10e6 / 2 ** 24
_AREG = 1e14 / 2 ** 41
_VMAX_REG_LIMIT = 0x7FFE00
_AMAX_REG_LIMIT = 0xFFFE
# Library scalings (UstepperS32.h) and rpmToVelocity for 200 full steps.
_VEL_CONV = 1.677
_ACC_CONV = 0.022
_RPM_TO_VREG = 279620.267 * 200 * 256 / 10e6
# No step for 2^20 clocks (stst) plus TPOWERDOWN = 20 * 2^18 clocks: the current drops to IHOLD.
_POWERDOWN_S = (2 ** 20 + 20 * 2 ** 18) / 10e6
# Physics resolution: field-rotor slip per sub-step (usteps), and omega_n * h per sub-step.
_SLIP_PER_SUBSTEP = 100.0
_WN_H = 0.4
_WALL_MARGIN = 64.0  # usteps: closer than this (plus a tick of travel) counts as touching a wall
_FAR = 1e30


class _Rng:
    """xorshift32 with Box-Muller normals: seeded, so runs repeat exactly."""

    def __init__(self, seed):
        self._s = ((seed * 2654435761) + 0x6D2B79F5) & 0xFFFFFFFF or 0x6D2B79F5
        self._spare = None
        for _ in range(4):
            self.next()

    def next(self):
        s = self._s
        s ^= (s << 13) & 0xFFFFFFFF
        s ^= s >> 17
        s ^= (s << 5) & 0xFFFFFFFF
        self._s = s
        return s

    def uniform(self):
        """In (0, 1)."""
        return (self.next() + 0.5) * 2.3283064365386963e-10

    def gauss(self):
        g = self._spare
        if g is not None:
            self._spare = None
            return g
        r = math.sqrt(-2.0 * math.log(self.uniform()))
        p = 2.0 * math.pi * self.uniform()
        self._spare = r * math.sin(p)
        return r * math.cos(p)


def _current_index(percent):
    """setCurrent/setHoldCurrent: percent to the TMC's 0..31 scale (out of range: 16)."""
    if 0.0 <= percent <= 100.0:
        return math.ceil(0.31 * percent)
    return 16


class SimStepper(MotorHAL):
    """uStepper S32 on a NEMA17 model. Parameters (SI, motor side) default to ustepper-model.md 8.3:

    holding_torque   N*m at full scale current (IRUN=31)
    inertia          kg*m^2, rotor plus reflected load
    damping          N*m*s/rad viscous; brake_damping is added by the coolbrake (coils shorted)
    coulomb          N*m dry friction (also the stiction limit)
    corner_speed     rad/s, torque roll-off T_max / (1 + |w| / corner_speed)
    wall_stiffness   N*m/rad, wall_damping N*m*s/rad: a wall as seen from the motor shaft
    enc_sigma        encoder white noise, counts (1 count = 360/32768 deg)
    enc_harmonics    amplitudes (deg) of the 1x and 2x per revolution encoder error, random phases
    wiring_sign      +1/-1: field direction per driver ustep with the shaft bit clear
    isr_skip_prob    probability that an ISR tick is skipped (SPI semaphore held by the main thread)
    enc_fail_prob    probability that an encoder sample is dropped (failed SPI transfer)
    """

    def __init__(self, clock, seed=1, holding_torque=0.45, inertia=2e-5, damping=2e-4, coulomb=0.005,
                 corner_speed=60.0, brake_damping=0.01, wall_stiffness=200.0, wall_damping=0.02, enc_sigma=0.7,
                 enc_harmonics=(0.15, 0.10), wiring_sign=1, isr_skip_prob=0.0, enc_fail_prob=0.0):
        self._clock = clock
        self._rng = rng = _Rng(seed)
        # Physics in usteps: torque (N*m) times _g is an angular acceleration in usteps/s^2.
        g = (_USTEPS_PER_REV / (2.0 * math.pi)) / inertia
        self._g = g
        self._acc_full = g * holding_torque
        self._visc = damping / inertia
        self._brake_visc = brake_damping / inertia
        self._fric = g * coulomb
        self._emf = _RAD_PER_USTEP / corner_speed
        self._kwall = wall_stiffness / inertia
        self._cwall = wall_damping / inertia
        self._nwall = 1 + int(_T_ISR * math.sqrt(self._kwall) / _WN_H)
        self._wiring = 1 if wiring_sign >= 0 else -1
        self._R = 0.0
        self._W = 0.0
        self._F = 0.0
        self._fx = 0.0  # field travel in driver usteps (what field_position() reports)
        self._load = 0.0
        self._stops = (-_FAR, _FAR)
        self._obstacles = []
        self._lo = -_FAR
        self._hi = _FAR
        # Encoder: magnet offset and harmonic error phases are properties of this board.
        self._mag = rng.uniform() * _COUNTS_PER_REV
        cpd = _COUNTS_PER_REV / 360.0
        self._h1 = enc_harmonics[0] * cpd
        self._h2 = enc_harmonics[1] * cpd
        self._p1 = 2.0 * math.pi * rng.uniform()
        self._p2 = 2.0 * math.pi * rng.uniform()
        self._sigma = enc_sigma
        self._skip_p = isr_skip_prob
        self._fail_p = enc_fail_prob
        # The ISR grid runs from construction at a random phase, so the firmware's polling is
        # free-running against it.
        self._t_next = clock.ticks_us() + _T_ISR_US * rng.uniform()
        self._ramp = Ramp()
        self._est = VelocityEstimator(_F_ISR)
        self._powered = False  # driver unconfigured before begin(): coils off, ISR not running
        self._reset_electronics()

    # ---- firmware reboot -------------------------------------------------------------------
    def _reset_electronics(self):
        ramp = self._ramp
        ramp.mode = POSITIONING
        ramp.x = 0.0
        ramp.v = 0.0
        ramp.xtarget = 0
        ramp.vmax = 0.0
        self._drv_xtarget = 0
        self._fdir = self._wiring
        self._irun = 13
        self._ihold = 13
        self._freewheel = 2
        self._since_step = 0.0
        self._max_vel = 100.0 * 256 * _VEL_CONV
        self._max_acc = 2000.0 * 256 * _ACC_CONV
        self._max_dec = 2000.0 * 256 * _ACC_CONV
        self._write_accel()
        self._stopping = False
        self._stop_hard = False
        self._pending_vmax = False
        self._pending_acc = False
        self._cl = False
        self._thr = 10.0
        self._pid = 0
        self._counts = 0
        self._home_raw = self._raw()
        self._est.reset()
        self._currents()

    def begin(self):
        """setup(CLOSEDLOOP, 200): encoder zeroed here, driver registers reset (XACTUAL 0, VMAX 0),
        currents 40 %/40 %, default profile, closed loop scheduled but inactive. A running ramp
        stops at once; the rotor and the field phase (MSCNT) stay where they are."""
        self._powered = True
        self._reset_electronics()

    # ---- driver/encoder internals ------------------------------------------------------------
    def _raw(self):
        """One encoder reading: unwrapped raw counts (angle + systematic error + noise)."""
        r = self._R * _RAD_PER_USTEP
        c = (self._R * _COUNTS_PER_USTEP + self._mag + self._h1 * math.sin(r + self._p1)
             + self._h2 * math.sin(2.0 * r + self._p2))
        if self._sigma:
            c += self._sigma * self._rng.gauss()
        return math.floor(c)

    def _currents(self):
        if not self._powered:
            self._a_run = self._a_hold = 0.0
            self._visc_hold = self._visc
        else:
            self._a_run = self._acc_full * (self._irun + 1) / 32.0
            if self._ihold == 0 and self._freewheel:
                self._a_hold = 0.0
                self._visc_hold = self._visc + (self._brake_visc if self._freewheel >= 2 else 0.0)
            else:
                self._a_hold = self._acc_full * (self._ihold + 1) / 32.0
                self._visc_hold = self._visc
        a = max(self._a_run, self._a_hold)
        self._nmin = 1 + int(_T_ISR * math.sqrt(a * _KE) / _WN_H)

    def _write_accel(self):
        self._ramp.amax = min(int(self._max_acc), _AMAX_REG_LIMIT) * _AREG
        self._ramp.dmax = min(int(self._max_dec), _AMAX_REG_LIMIT) * _AREG

    def _vmax_reg(self):
        return min(int(self._max_vel), _VMAX_REG_LIMIT)

    def _end_stop(self):
        """A pending stop ends: the registers it saved or that were set meanwhile apply."""
        if self._stopping:
            self._stopping = False
            if self._stop_hard or self._pending_acc:
                self._write_accel()
            if self._pending_vmax:
                self._ramp.vmax = self._vmax_reg() * _VREG
            self._pending_acc = self._pending_vmax = False

    def _finish_stop(self):
        # stop(): after VACTUAL reached 0, setPosition(XACTUAL), VMAX stays 0.
        self._end_stop()
        ramp = self._ramp
        xa = ramp.xactual()
        ramp.x = float(xa)
        ramp.mode = POSITIONING
        ramp.xtarget = xa
        self._drv_xtarget = xa

    def _set_rpm(self, rpm):
        ramp = self._ramp
        vreg = int(rpm * _RPM_TO_VREG)
        ramp.mode = VELOCITY_POS if vreg > 0 else VELOCITY_NEG
        ramp.vmax = min(abs(vreg), _VMAX_REG_LIMIT) * _VREG

    # ---- simulation --------------------------------------------------------------------------
    def update(self):
        """Integrate up to clock.ticks_us(): per ISR period the ramp, the rotor, then the ISR."""
        now = self._clock.ticks_us()
        t_next = self._t_next
        if now < t_next:
            return
        ramp = self._ramp
        est = self._est
        rng = self._rng
        sin = math.sin
        floor = math.floor
        T = _T_ISR
        R, W, F = self._R, self._W, self._F
        fx = self._fx
        lo, hi, kw, cw = self._lo, self._hi, self._kwall, self._cwall
        load, fric, emf = self._load, self._fric, self._emf
        since = self._since_step
        isr_on = self._powered
        cl, thr, counts = self._cl, self._thr, self._counts
        pid, home = self._pid, self._home_raw
        skip_p, fail_p, sigma = self._skip_p, self._fail_p, self._sigma
        mag, h1, h2, p1, p2 = self._mag, self._h1, self._h2, self._p1, self._p2
        r_enc = None  # rotor position of the cached noise-free encoder reading c_enc
        c_enc = 0.0
        while t_next <= now:
            t_next += _T_ISR_US
            # Driver: one ISR period of the ramp; the field follows the steps, not XACTUAL writes.
            if ramp.v == 0.0 and ramp.mode == POSITIONING and ramp.x == ramp.xtarget:
                dx = 0.0
            else:
                dx = ramp.step(T)
                fx += dx
                if self._stopping and ramp.v == 0.0:
                    self._finish_stop()
            if dx != 0.0:
                since = 0.0
                va = self._a_run
                visc = self._visc
            else:
                since += T
                if since < _POWERDOWN_S:
                    va = self._a_run
                    visc = self._visc
                else:
                    va = self._a_hold
                    visc = self._visc_hold
            vf = self._fdir * dx / T
            # Rotor: skipped while it and the field rest, held by friction.
            moving = W != 0.0 or vf != 0.0
            if not moving:
                net = va * sin(_KE * (F - R)) - load
                if R > hi:
                    net -= kw * (R - hi)
                elif R < lo:
                    net -= kw * (R - lo)
                moving = not -fric <= net <= fric
            if moving:
                n = self._nmin + int(abs(vf - W) * T / _SLIP_PER_SUBSTEP)
                reach = (abs(W) + abs(vf)) * T + _WALL_MARGIN
                if (hi - R < reach or R - lo < reach) and n < self._nwall:
                    n = self._nwall
                h = T / n
                fh = fric * h
                df = vf * h
                for _ in range(n):
                    a = va * sin(_KE * (F - R)) / (1.0 + abs(W) * emf) - visc * W - load
                    # Walls push back like a spring, damped only while compressed (never pull).
                    if R > hi:
                        a -= kw * (R - hi) + (cw * W if W > 0.0 else 0.0)
                    elif R < lo:
                        a -= kw * (R - lo) + (cw * W if W < 0.0 else 0.0)
                    W += a * h
                    if W > fh:
                        W -= fh
                    elif W < -fh:
                        W += fh
                    else:
                        W = 0.0
                    R += W * h
                    F += df
            # Library ISR: encoder sample, velocity estimator, closed-loop re-synchronisation.
            if not isr_on or (skip_p and rng.uniform() < skip_p):
                continue
            if not (fail_p and rng.uniform() < fail_p):
                if R != r_enc:
                    r_enc = R
                    r = R * _RAD_PER_USTEP
                    c_enc = R * _COUNTS_PER_USTEP + mag + h1 * sin(r + p1) + h2 * sin(2.0 * r + p2)
                c = c_enc
                if sigma:
                    c += sigma * rng.gauss()
                counts = floor(c) - home
                est.update(counts)
            if cl:
                meas = int(1.5625 * counts)
                pid = floor(ramp.x + 0.5) - meas
                if pid >= thr or -pid >= thr:
                    ramp.x = float(meas)
                    if ramp.mode == POSITIONING:
                        ramp.xtarget = self._drv_xtarget
        self._t_next = t_next
        self._R, self._W, self._F = R, W, F
        self._fx = fx
        self._since_step = since
        self._counts, self._pid = counts, pid

    # ---- MotorHAL ----------------------------------------------------------------------------
    def enable_closed_loop(self):
        self._cl = True

    def disable_closed_loop(self):
        self._cl = False

    def set_control_threshold(self, usteps):
        self._thr = float(usteps)

    def set_max_velocity(self, full_steps_per_s):
        self._max_vel = abs(full_steps_per_s) * 256 * _VEL_CONV
        if self._stopping:
            self._pending_vmax = True
        else:
            self._ramp.vmax = self._vmax_reg() * _VREG

    def set_max_acceleration(self, full_steps_per_s2):
        self._max_acc = abs(full_steps_per_s2) * 256 * _ACC_CONV
        if self._stopping:
            self._pending_acc = True
        else:
            self._ramp.amax = min(int(self._max_acc), _AMAX_REG_LIMIT) * _AREG

    def set_max_deceleration(self, full_steps_per_s2):
        self._max_dec = abs(full_steps_per_s2) * 256 * _ACC_CONV
        if self._stopping:
            self._pending_acc = True
        else:
            self._ramp.dmax = min(int(self._max_dec), _AMAX_REG_LIMIT) * _AREG

    def set_rpm(self, rpm):
        """setRPM: VMAX and velocity mode only; the ramp uses the current AMAX both ways."""
        self._end_stop()
        self._set_rpm(rpm)

    def move_steps(self, usteps):
        self._end_stop()
        ramp = self._ramp
        # moveSteps casts AMAX/DMAX through uint16 (wraps above 65535), then the driver clamps.
        ramp.dmax = min(int(self._max_dec) & 0xFFFF, _AMAX_REG_LIMIT) * _AREG
        ramp.amax = min(int(self._max_acc) & 0xFFFF, _AMAX_REG_LIMIT) * _AREG
        ramp.vmax = self._vmax_reg() * _VREG
        target = ramp.xactual() + int(usteps)
        ramp.mode = POSITIONING
        ramp.xtarget = target
        self._drv_xtarget = target

    def move_angle(self, degrees):
        if degrees < 0.0:
            self.move_steps(int(degrees * _ANGLE_TO_STEP - 0.5))
        else:
            self.move_steps(int(degrees * _ANGLE_TO_STEP + 0.5))

    def move_to_angle(self, degrees):
        diff = degrees - self.angle_moved()
        steps = int(abs(diff) * _ANGLE_TO_STEP + 0.5)
        self.move_steps(-steps if diff < 0.0 else steps)

    def stop(self, hard=True):
        """Starts the library's stop(): velocity ramp to 0 (hard: at the driver's maximum
        deceleration, ~11641 fs/s^2; soft: at AMAX), then hold XACTUAL in positioning mode with
        VMAX 0. The library busy-waits; here update() completes it when VACTUAL reaches 0."""
        self._end_stop()
        if hard:
            self._ramp.amax = self._ramp.dmax = _AMAX_REG_LIMIT * _AREG
        self._set_rpm(0)
        self._stopping = True
        self._stop_hard = hard
        if self._ramp.v == 0.0:
            self._finish_stop()

    def set_current(self, percent):
        self._irun = _current_index(percent)
        self._currents()

    def set_hold_current(self, percent):
        self._ihold = _current_index(percent)
        self._currents()

    def set_brake_mode(self, mode):
        """0 freewheel (coils open at standstill), 1 coolbrake (coils shorted: viscous braking,
        no holding torque), 2 hardbrake (25 % holding current). 0 and 1 set IHOLD to 0."""
        if mode == 0 or mode == 1:
            self._ihold = 0
            self._freewheel = mode + 1
        else:
            self._ihold = _current_index(25.0)
            self._freewheel = 0
        self._currents()

    def set_home(self):
        """encoder.setHome() and driver.setHome(): both zeroed here; a positioning move keeps its
        remaining distance."""
        self._home_raw = self._raw()
        self._counts = 0
        self._est.reset()
        ramp = self._ramp
        if ramp.mode == POSITIONING:
            target = ramp.xtarget - ramp.xactual()
        else:
            target = 0
        ramp.set_position(0)
        ramp.xtarget = target
        self._drv_xtarget = target

    def set_inverted(self, inverted):
        self._fdir = -self._wiring if inverted else self._wiring

    def angle_moved(self):
        return self._counts * (360.0 / _COUNTS_PER_REV)

    def encoder_rpm(self):
        return self._est.value * (60.0 / _COUNTS_PER_REV)

    def driver_rpm(self):
        """True ramp speed (the library's getDriverRPM under-reports by 1.677, not modelled)."""
        return self._ramp.v * (60.0 / _USTEPS_PER_REV)

    def pid_error(self):
        return float(self._pid)

    def position_reached(self):
        return self._ramp.position_reached()

    def field_position(self):
        return int(math.floor(self._fx + 0.5)) & 0x3FFFFFFF

    # ---- simulator hooks ---------------------------------------------------------------------
    def driver_position(self):
        return self._ramp.xactual()

    def rotor_angle(self):
        return self._R / _ANGLE_TO_STEP

    def set_end_stops(self, low_deg=None, high_deg=None):
        self._stops = (-_FAR if low_deg is None else low_deg * _ANGLE_TO_STEP,
                       _FAR if high_deg is None else high_deg * _ANGLE_TO_STEP)
        self._walls()

    def add_obstacle(self, angle_deg, direction):
        self._obstacles.append((angle_deg * _ANGLE_TO_STEP, 1 if direction > 0 else -1))
        self._walls()

    def clear_obstacles(self):
        self._obstacles = []
        self._walls()

    def block(self):
        w = self._W
        if abs(w) < 1.0:
            w = self._fdir * self._ramp.v
        self._obstacles.append((self._R, -1 if w < 0.0 else 1))
        self._walls()

    def set_load_torque(self, nm):
        self._load = nm * self._g

    def _walls(self):
        lo, hi = self._stops
        for at, direction in self._obstacles:
            if direction > 0:
                hi = min(hi, at)
            else:
                lo = max(lo, at)
        self._lo, self._hi = lo, hi
