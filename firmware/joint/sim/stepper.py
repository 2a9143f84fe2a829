"""Simulated uStepper S32: TMC5130 ramp generator, stepper rotor, TLE5012B encoder and the library's
1541.85 Hz ISR (encoder sample, velocity estimator, closed-loop re-synchronisation), behind MotorHAL.

Behaviour follows reference/ustepper-model.md sections 2-5 and 8: the "PID error" is the driver
position minus the encoder position, the closed loop only relabels XACTUAL (the field keeps turning),
so a blocked rotor shows a bounded error with pole-slip spikes, never a growing one.

Physics (Level 2 of section 8.4, integrated cheaply): the rotor is an inertia pulled toward the
field by T_max*sin(2*pi*(F - R)/1024) (50 pole pairs), T_max = T_hold*(I+1)/32 rolled off by back-EMF,
minus viscous, Coulomb (with stiction) and external load torque. With a load (load_inertia > 0) the
rotor drives a second inertia, the link reflected through the reduction, over a spring-damper with
a dead band (belt or lead-screw compliance, backlash); the load carries its own friction, a constant
torque (gravity on a vertical axis) and the walls. Without one the walls act on the rotor itself.
Sub-steps are laid on the ISR grid, as many per ISR period as the slip speed and the electrical
stiffness need (one to a few in synchronous running, more while slipping), and none while
everything rests. Coupling, viscous and wall forces are integrated implicitly (backward Euler, a
2x2 solve per sub-step), so a wall or a coupling of any stiffness and damping stays stable and
never throws the rotor back; the magnetic torque and friction are explicit. Walls are one-sided
springs, damped only while being compressed.

Frames: R (rotor) and F (field) are mechanical usteps in the physical frame, 0 = rotor angle at
construction; the field advances by wiring_sign * (shaft ? -1 : 1) per driver ustep. The load L is
in the same motor frame (joint angle times the reduction, 0 = where it started). The encoder sits
on the rotor; its counts grow with R (the connector/magnet orientation is folded into wiring_sign).

Simulator hooks (not part of MotorHAL):
    rotor_angle()                  true rotor angle, motor degrees (0 = at construction)
    slipped_periods()              electrical periods lost (pole slips) since construction
    load_angle()                   true position of the driven link in motor degrees (the rotor
                                   when there is no load model)
    set_end_stops(low_deg=None, high_deg=None)   one-sided walls on the load (None: no wall)
    add_obstacle(angle_deg, direction, stiffness=None, damping=None)
                                   a wall at angle_deg blocking motion in direction +1/-1, with its
                                   own stiffness (N*m/rad) and damping (N*m*s/rad) as seen from the
                                   motor (default: the end stops')
    clear_obstacles()              remove the obstacles (end stops stay)
    block(stiffness=None, damping=None)
                                   a wall where the load is now, against its direction of motion
                                   (its speed, else the field's; +1 when both rest)
    set_load_torque(nm)            external torque on the load (on top of the constant load_torque);
                                   positive pushes toward negative angles
    driver_position()              XACTUAL, usteps
Walls belong on the side the load is not on: one placed behind it pushes it out like a
compressed spring. A collision of the arm seen through the joint reduction N is far softer than
the same contact on the motor shaft (joint stiffness / N^2); mechanics.py has the arm's values.

Before begin() the driver is unconfigured: coils off, ISR not running. stop() does not busy-wait as
the library does: it starts the deceleration and update() completes it. driver_rpm() reports the
true ramp speed, not the library's 0.596x figure.
"""

import math

from ..motion.hal import MotorHAL
from .ramp import Ramp, POSITIONING, VELOCITY_POS, VELOCITY_NEG
from ..motion.velocity import VelocityEstimator

_F_ISR = 1541.85
_T_ISR = 1.0 / _F_ISR
_T_ISR_US = 1e6 / _F_ISR
_USTEPS_PER_REV = 51200.0
_COUNTS_PER_REV = 32768.0
_ANGLE_TO_STEP = 51200.0 / 360.0
_KE = 2.0 * math.pi / 1024.0  # electrical radians per ustep (one period = 4 full steps)
_RAD_PER_USTEP = 2.0 * math.pi / _USTEPS_PER_REV
_USTEPS_PER_RAD = _USTEPS_PER_REV / (2.0 * math.pi)
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
_WN_H_CPL = 0.8  # the coupling and walls are implicit: sub-stepped for accuracy only
_MAX_WALL_SUBSTEPS = 8
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
    inertia          kg*m^2, the rotor and what turns rigidly with it (all of the load when
                     load_inertia is 0)
    damping          N*m*s/rad viscous; brake_damping is added by the coolbrake (coils shorted)
    coulomb          N*m dry friction (also the stiction limit)
    corner_speed     rad/s, torque roll-off T_max / (1 + |w| / corner_speed)
    wall_stiffness   N*m/rad, wall_damping N*m*s/rad: the end stops as seen from the motor shaft
    enc_sigma        encoder white noise, counts (1 count = 360/counts_per_rev deg)
    enc_harmonics    amplitudes (deg) of the 1x and 2x per revolution encoder error, random phases
    counts_per_rev   encoder resolution: 32768 (TLE5012B, 15 bit) or 4096 (AS5600, 12 bit)
    wiring_sign      +1/-1: field direction per driver ustep with the shaft bit clear
    isr_skip_prob    probability that an ISR tick is skipped (SPI semaphore held by the main thread)
    enc_fail_prob    probability that an encoder sample is dropped (failed SPI transfer)
    load_inertia     kg*m^2, the driven link reflected to the motor (J_joint / N^2); 0: rigid
    coupling_stiffness, coupling_damping   N*m/rad, N*m*s/rad of the transmission, motor side
    backlash         motor degrees of play in the transmission (total)
    load_damping, load_friction   N*m*s/rad, N*m on the load, motor side
    load_torque      N*m constant torque on the load (gravity), positive toward negative angles
    """

    def __init__(self, clock, seed=1, holding_torque=0.45, inertia=2e-5, damping=2e-4, coulomb=0.005,
                 corner_speed=60.0, brake_damping=0.01, wall_stiffness=200.0, wall_damping=0.02, enc_sigma=0.7,
                 enc_harmonics=(0.15, 0.10), wiring_sign=1, isr_skip_prob=0.0, enc_fail_prob=0.0,
                 counts_per_rev=32768, load_inertia=0.0, coupling_stiffness=1.0, coupling_damping=0.0,
                 backlash=0.0, load_damping=0.0, load_friction=0.0, load_torque=0.0):
        self._clock = clock
        self._rng = rng = _Rng(seed)
        # Physics in usteps: torque (N*m) times _g is an angular acceleration in usteps/s^2.
        g = _USTEPS_PER_RAD / inertia
        self._g = g
        self._acc_full = g * holding_torque
        self._visc = damping / inertia
        self._brake_visc = brake_damping / inertia
        self._fric = g * coulomb
        self._emf = _RAD_PER_USTEP / corner_speed
        self._wiring = 1 if wiring_sign >= 0 else -1
        # The load: with none, the walls and the load torque act on the rotor itself.
        self._two = load_inertia > 0.0
        jl = load_inertia if self._two else inertia
        self._gl = _USTEPS_PER_RAD / jl
        self._kr = coupling_stiffness / inertia
        self._cr = coupling_damping / inertia
        self._kl = coupling_stiffness / jl
        self._cl = coupling_damping / jl
        self._gap = 0.5 * backlash * _ANGLE_TO_STEP
        self._visc_l = load_damping / jl
        self._fric_l = self._gl * load_friction
        self._ncpl = (1 + int(_T_ISR * math.sqrt(coupling_stiffness * (1.0 / inertia + 1.0 / jl)) / _WN_H_CPL)
                      if self._two else 1)
        self._wall = (wall_stiffness / jl, wall_damping / jl)
        self._jl = jl
        self._R = 0.0
        self._W = 0.0
        self._field = 0.0  # usteps the driver has stepped since begin(), without XACTUAL relabels
        self._L = 0.0
        self._V = 0.0
        self._F = 0.0
        self._gravity = load_torque
        self._ext = 0.0
        self._load = self._gl * load_torque
        self._stops = (-_FAR, _FAR)
        self._obstacles = []
        self._lo = -_FAR
        self._hi = _FAR
        self._walls()
        # Encoder: magnet offset and harmonic error phases are properties of this board.
        self._cpr = float(counts_per_rev)
        self._cpu = self._cpr / _USTEPS_PER_REV  # counts per ustep
        self._upc = _USTEPS_PER_REV / self._cpr  # usteps per count (the closed loop's conversion)
        self._mag = rng.uniform() * self._cpr
        cpd = self._cpr / 360.0
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
        self._field = 0.0
        self._reset_electronics()

    # ---- driver/encoder internals ------------------------------------------------------------
    def _raw(self):
        """One encoder reading: unwrapped raw counts (angle + systematic error + noise)."""
        r = self._R * _RAD_PER_USTEP
        c = (self._R * self._cpu + self._mag + self._h1 * math.sin(r + self._p1)
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
        """Integrate up to clock.ticks_us(): per ISR period the ramp, the mechanics, then the ISR."""
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
        two = self._two
        R, W, L, V, F = self._R, self._W, self._L, self._V, self._F
        lo, hi = self._lo, self._hi
        klo, clo = self._wlo
        khi, chi = self._whi
        load, fric, emf = self._load, self._fric, self._emf
        kr, cr, kl, cl, gap = self._kr, self._cr, self._kl, self._cl, self._gap
        visc_l, fric_l = self._visc_l, self._fric_l
        since = self._since_step
        field = self._field
        isr_on = self._powered
        cl_on, thr, counts = self._cl, self._thr, self._counts
        pid, home = self._pid, self._home_raw
        skip_p, fail_p, sigma = self._skip_p, self._fail_p, self._sigma
        mag, h1, h2, p1, p2 = self._mag, self._h1, self._h2, self._p1, self._p2
        cpu, upc = self._cpu, self._upc
        r_enc = None  # rotor position of the cached noise-free encoder reading c_enc
        c_enc = 0.0
        while t_next <= now:
            t_next += _T_ISR_US
            # Driver: one ISR period of the ramp; the field follows the steps, not XACTUAL writes.
            if ramp.v == 0.0 and ramp.mode == POSITIONING and ramp.x == ramp.xtarget:
                dx = 0.0
            else:
                dx = ramp.step(T)
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
            field += dx
            vf = self._fdir * dx / T
            # Mechanics: skipped while everything and the field rest, held by friction.
            moving = W != 0.0 or V != 0.0 or vf != 0.0
            if not moving:
                x = L if two else R
                wall = khi * (x - hi) if x > hi else (klo * (x - lo) if x < lo else 0.0)
                net = va * sin(_KE * (F - R))
                if two:
                    d = R - L
                    tw = d - gap if d > gap else (d + gap if d < -gap else 0.0)
                    net -= kr * tw
                    net_l = kl * tw - load - wall
                else:
                    net -= load + wall
                    net_l = 0.0
                moving = not (-fric <= net <= fric and -fric_l <= net_l <= fric_l)
            if moving:
                n = self._nmin + int(abs(vf - W) * T / _SLIP_PER_SUBSTEP)
                if n < self._ncpl:
                    n = self._ncpl
                x, v = (L, V) if two else (R, W)
                reach = (abs(v) + abs(vf)) * T + _WALL_MARGIN
                if hi - x < reach and n < self._nhi:
                    n = self._nhi
                if x - lo < reach and n < self._nlo:
                    n = self._nlo
                h = T / n
                hh = h * h
                fh = fric * h
                flh = fric_l * h
                df = vf * h
                for _ in range(n):
                    ar = va * sin(_KE * (F - R)) / (1.0 + abs(W) * emf)
                    if two:
                        # Implicit coupling (when engaged), viscous and wall terms: a 2x2 solve.
                        a11 = 1.0 + h * visc
                        a22 = 1.0 + h * visc_l
                        a12 = a21 = 0.0
                        b1 = W + h * ar
                        b2 = V - h * load
                        d = R - L
                        if d > gap or d < -gap:
                            tw = d - gap if d > gap else d + gap
                            sr = hh * kr + h * cr
                            sl = hh * kl + h * cl
                            a11 += sr
                            a22 += sl
                            a12 = -sr
                            a21 = -sl
                            b1 -= h * kr * tw
                            b2 += h * kl * tw
                        if L > hi:
                            b2 -= h * khi * (L - hi)
                            a22 += hh * khi + (h * chi if V > 0.0 else 0.0)
                        elif L < lo:
                            b2 -= h * klo * (L - lo)
                            a22 += hh * klo + (h * clo if V < 0.0 else 0.0)
                        det = a11 * a22 - a12 * a21
                        W = (b1 * a22 - a12 * b2) / det
                        V = (a11 * b2 - a21 * b1) / det
                        if V > flh:
                            V -= flh
                        elif V < -flh:
                            V += flh
                        else:
                            V = 0.0
                    else:
                        # Implicit viscous and wall terms on the rotor alone.
                        b1 = W + h * (ar - load)
                        a11 = 1.0 + h * visc
                        if R > hi:
                            b1 -= h * khi * (R - hi)
                            a11 += hh * khi + (h * chi if W > 0.0 else 0.0)
                        elif R < lo:
                            b1 -= h * klo * (R - lo)
                            a11 += hh * klo + (h * clo if W < 0.0 else 0.0)
                        W = b1 / a11
                    if W > fh:
                        W -= fh
                    elif W < -fh:
                        W += fh
                    else:
                        W = 0.0
                    R += W * h
                    L += V * h
                    F += df
                if not two:
                    L, V = R, W
            # Library ISR: encoder sample, velocity estimator, closed-loop re-synchronisation.
            if not isr_on or (skip_p and rng.uniform() < skip_p):
                continue
            if not (fail_p and rng.uniform() < fail_p):
                if R != r_enc:
                    r_enc = R
                    r = R * _RAD_PER_USTEP
                    c_enc = R * cpu + mag + h1 * sin(r + p1) + h2 * sin(2.0 * r + p2)
                c = c_enc
                if sigma:
                    c += sigma * rng.gauss()
                counts = floor(c) - home
                est.update(counts)
            if cl_on:
                meas = int(upc * counts)
                pid = floor(ramp.x + 0.5) - meas
                if pid >= thr or -pid >= thr:
                    ramp.x = float(meas)
                    if ramp.mode == POSITIONING:
                        ramp.xtarget = self._drv_xtarget
        self._t_next = t_next
        self._R, self._W, self._L, self._V, self._F = R, W, L, V, F
        self._since_step = since
        self._field = field
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
        return self._counts * (360.0 / self._cpr)

    def encoder_rpm(self):
        return self._est.value * (60.0 / self._cpr)

    def driver_rpm(self):
        """True ramp speed (the library's getDriverRPM under-reports by 1.677, not modelled)."""
        return self._ramp.v * (60.0 / _USTEPS_PER_REV)

    def pid_error(self):
        return float(self._pid)

    def position_reached(self):
        return self._ramp.position_reached()

    def field_position(self):
        """Usteps the driver has advanced the coil field since begin(): XACTUAL without the closed
        loop's relabels (set_home() does not reset it)."""
        return int(math.floor(self._field + 0.5))

    # ---- simulator hooks ---------------------------------------------------------------------
    def driver_position(self):
        return self._ramp.xactual()

    def rotor_angle(self):
        return self._R / _ANGLE_TO_STEP

    def slipped_periods(self):
        """Whole electrical periods (4 full steps) the rotor has fallen behind or run ahead of the
        coil field since construction: nonzero once the motor has lost steps."""
        return int(math.floor((self._F - self._R) / 1024.0 + 0.5))

    def load_angle(self):
        return (self._L if self._two else self._R) / _ANGLE_TO_STEP

    def set_end_stops(self, low_deg=None, high_deg=None):
        self._stops = (-_FAR if low_deg is None else low_deg * _ANGLE_TO_STEP,
                       _FAR if high_deg is None else high_deg * _ANGLE_TO_STEP)
        self._walls()

    def add_obstacle(self, angle_deg, direction, stiffness=None, damping=None):
        self._add(angle_deg * _ANGLE_TO_STEP, direction, stiffness, damping)

    def clear_obstacles(self):
        self._obstacles = []
        self._walls()

    def block(self, stiffness=None, damping=None):
        x, v = (self._L, self._V) if self._two else (self._R, self._W)
        if abs(v) < 1.0:
            v = self._fdir * self._ramp.v
        self._add(x, -1 if v < 0.0 else 1, stiffness, damping)

    def set_load_torque(self, nm):
        self._ext = nm
        self._load = self._gl * (self._gravity + nm)

    def _add(self, at, direction, stiffness, damping):
        k, c = self._wall
        if stiffness is not None:
            k = stiffness / self._jl
        if damping is not None:
            c = damping / self._jl
        self._obstacles.append((at, 1 if direction > 0 else -1, k, c))
        self._walls()

    def _walls(self):
        """The tightest wall on each side, with its stiffness and damping (load accel units)."""
        lo, hi = self._stops
        wlo = whi = self._wall
        for at, direction, k, c in self._obstacles:
            if direction > 0:
                if at < hi:
                    hi, whi = at, (k, c)
            elif at > lo:
                lo, wlo = at, (k, c)
        self._lo, self._hi = lo, hi
        self._wlo, self._whi = wlo, whi
        # Implicit walls are stable at any stiffness; sub-steps only resolve the impact.
        self._nlo = min(_MAX_WALL_SUBSTEPS, 1 + int(_T_ISR * math.sqrt(wlo[0]) / _WN_H_CPL))
        self._nhi = min(_MAX_WALL_SUBSTEPS, 1 + int(_T_ISR * math.sqrt(whi[0]) / _WN_H_CPL))
