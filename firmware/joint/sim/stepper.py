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
everything rests. The magnetic torque and the coupling spring are explicit (symplectic Euler, no
numerical damping; sub-stepped to omega*h <= 0.4), the coupling damper and viscous terms use the
trapezoidal rule (no numerical damping), so the link rings and decays as its equations say
(bench/sim_reference.py checks it against scipy's solve_ivp within 2 %); the walls are implicit
(backward Euler, a 2x2 solve per sub-step), so a wall of any stiffness and damping stays stable
and never throws the rotor back. Walls are one-sided springs, damped only while being compressed.

Frames: R (rotor) and F (field) are mechanical usteps in the physical frame, 0 = rotor angle at
construction; the field advances by wiring_sign * (shaft ? -1 : 1) per driver ustep. The load L is
in the same motor frame (joint angle times the reduction, 0 = where it started). The encoder sits
on the rotor; its counts grow with R (the connector/magnet orientation is folded into wiring_sign).

Simulator hooks (not part of MotorHAL):
    rotor_angle()                  true rotor angle, motor degrees (0 = at construction)
    slipped_periods()              electrical periods lost (pole slips) since construction
    encoder_error(rotor_deg)       what the firmware's encoder reading (noise-free, calibrated as set) is
                                   off by at that true rotor angle, degrees, up to a constant
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
    weaken_magnet(noise_factor=20, harmonics_deg=(20.0, 10.0), reports=MAGNET_WEAK)
                                   the fault mode of ustepper-model.md 8.3: encoder noise x factor and
                                   a large harmonic error (a weak or displaced magnet); the sensor's
                                   status then says `reports` (hal.MAGNET_*: MAGNET_MISSING for a
                                   magnet gone, MAGNET_OK for a marginal one its status misses)
Walls belong on the side the load is not on: one placed behind it pushes it out like a
compressed spring. A collision of the arm seen through the joint reduction N is far softer than
the same contact on the motor shaft (joint stiffness / N^2); mechanics.py has the arm's values.

Before begin() the driver is unconfigured: coils off, ISR not running. stop() does not busy-wait as
the library does: it starts the deceleration and update() completes it. driver_rpm() reports the
true ramp speed, not the library's 0.596x figure.
"""

import math

from ..motion.hal import MAGNET_OK, MAGNET_WEAK, MotorHAL
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
_WN_H_CPL = 0.4  # the coupling spring is explicit: stable below 2, frequency within 0.7 % here
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
    enc_harmonics    the datasheet's bound (deg) on the 1x and 2x per revolution encoder error; this
                     board's amplitudes are drawn within it (30..100 %) and its phases at random,
                     per seed and `encoder_board`, from a stream of their own (the seed's other
                     draws stay as they were)
    encoder_board    which sensor of the arm this is (mechanics.py: 1..4 for J1..J4): joints built
                     on one seed still get errors of their own
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
                 backlash=0.0, load_damping=0.0, load_friction=0.0, load_torque=0.0, encoder_board=0):
        self._clock = clock
        self._rng = rng = _Rng(seed)
        # Physics in usteps (ustepper-model.md 8.4 Level 2, divided by the inertia): a torque (N*m)
        # times _accel_per_nm is the rotor's angular acceleration in usteps/s^2; *_rate terms are
        # damping (N*m*s/rad) per inertia, 1/s; coupling_stiffness_* stiffness per inertia, 1/s^2.
        g = _USTEPS_PER_RAD / inertia
        self._accel_per_nm = g
        self._field_accel_full = g * holding_torque
        self._rotor_damping_rate = damping / inertia
        self._brake_damping_rate = brake_damping / inertia
        self._rotor_friction_accel = g * coulomb
        self._backemf_per_speed = _RAD_PER_USTEP / corner_speed
        self._wiring_sign = 1 if wiring_sign >= 0 else -1
        # The load: with none, the walls and the load torque act on the rotor itself.
        self._has_load = load_inertia > 0.0
        jl = load_inertia if self._has_load else inertia
        self._load_accel_per_nm = _USTEPS_PER_RAD / jl
        self._coupling_stiffness_rotor = coupling_stiffness / inertia
        self._coupling_damping_rotor = coupling_damping / inertia
        self._coupling_stiffness_load = coupling_stiffness / jl
        self._coupling_damping_load = coupling_damping / jl
        self._backlash_half = 0.5 * backlash * _ANGLE_TO_STEP
        self._load_damping_rate = load_damping / jl
        self._load_friction_accel = self._load_accel_per_nm * load_friction
        coupling_wn = math.sqrt(coupling_stiffness * (1.0 / inertia + 1.0 / jl))  # rad/s
        self._coupling_substeps = 1 + int(_T_ISR * coupling_wn / _WN_H_CPL) if self._has_load else 1
        self._end_stop_rates = (wall_stiffness / jl, wall_damping / jl)
        self._load_inertia = jl
        self._rotor = 0.0
        self._rotor_speed = 0.0
        self._field = 0.0  # usteps the driver has stepped since begin(), without XACTUAL relabels
        self._load_pos = 0.0
        self._load_speed = 0.0
        self._field_angle = 0.0
        self._load_torque_nm = load_torque
        self._external_torque_nm = 0.0
        self._load_torque_accel = self._load_accel_per_nm * load_torque
        self._stops = (-_FAR, _FAR)
        self._obstacles = []
        self._low_wall = -_FAR
        self._high_wall = _FAR
        self._walls()
        # Encoder: magnet offset and harmonic error phases are properties of this board.
        self._counts_per_rev = float(counts_per_rev)
        self._encoder_cpr = int(counts_per_rev)
        self._counts_per_ustep = self._counts_per_rev / _USTEPS_PER_REV
        self._usteps_per_count = _USTEPS_PER_REV / self._counts_per_rev  # the closed loop's conversion
        self._magnet_offset = rng.uniform() * self._counts_per_rev
        cpd = self._counts_per_rev / 360.0
        board = _Rng((seed * 31 + encoder_board) ^ 0x5EED0E5C)
        self._harmonic1_counts = enc_harmonics[0] * cpd * (0.3 + 0.7 * board.uniform())
        self._harmonic2_counts = enc_harmonics[1] * cpd * (0.3 + 0.7 * board.uniform())
        self._harmonic1_phase = 2.0 * math.pi * (rng.uniform() + board.uniform())
        self._harmonic2_phase = 2.0 * math.pi * (rng.uniform() + board.uniform())
        self._noise_counts = enc_sigma
        self._magnet = MAGNET_OK  # what the sensor's status says (weaken_magnet)
        self._isr_skip_prob = isr_skip_prob
        self._enc_fail_prob = enc_fail_prob
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
        self._field_dir = self._wiring_sign
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
        self._closed_loop = False
        self._control_threshold = 10.0
        self._pid_error = 0
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
        """One encoder reading as the firmware takes it: unwrapped raw counts (angle + systematic
        error + noise), less its calibrated error (set_encoder_correction)."""
        c = self._noise_free(self._rotor)
        if self._noise_counts:
            c += self._noise_counts * self._rng.gauss()
        return self._corrected(math.floor(c))

    def _noise_free(self, rotor):
        """The sensor's counts (unwrapped, not floored) at `rotor` usteps: angle + systematic error.
        update() inlines the same sum on its hot path."""
        r = rotor * _RAD_PER_USTEP
        return (rotor * self._counts_per_ustep + self._magnet_offset
                + self._harmonic1_counts * math.sin(r + self._harmonic1_phase)
                + self._harmonic2_counts * math.sin(2.0 * r + self._harmonic2_phase))

    def _currents(self):
        if not self._powered:
            self._run_accel = self._hold_accel = 0.0
            self._hold_damping_rate = self._rotor_damping_rate
        else:
            self._run_accel = self._field_accel_full * (self._irun + 1) / 32.0
            if self._ihold == 0 and self._freewheel:
                self._hold_accel = 0.0
                brake = self._brake_damping_rate if self._freewheel >= 2 else 0.0
                self._hold_damping_rate = self._rotor_damping_rate + brake
            else:
                self._hold_accel = self._field_accel_full * (self._ihold + 1) / 32.0
                self._hold_damping_rate = self._rotor_damping_rate
        a = max(self._run_accel, self._hold_accel)
        self._min_substeps = 1 + int(_T_ISR * math.sqrt(a * _KE) / _WN_H)

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
        has_load = self._has_load
        # The state in ustepper-model.md 8.4's symbols: R rotor, F field (usteps), W rotor speed;
        # L load, V load speed (usteps, usteps/s, motor side). Rates are per inertia (1/s^2, 1/s).
        R, W, L, V, F = self._rotor, self._rotor_speed, self._load_pos, self._load_speed, self._field_angle
        lo, hi = self._low_wall, self._high_wall
        klo, clo = self._low_wall_rates
        khi, chi = self._high_wall_rates
        load, fric, emf = self._load_torque_accel, self._rotor_friction_accel, self._backemf_per_speed
        k_rotor, c_rotor = self._coupling_stiffness_rotor, self._coupling_damping_rotor
        k_load, c_load, gap = self._coupling_stiffness_load, self._coupling_damping_load, self._backlash_half
        visc_load, fric_load = self._load_damping_rate, self._load_friction_accel
        since = self._since_step
        field = self._field
        isr_on = self._powered
        cl_on, thr, counts = self._closed_loop, self._control_threshold, self._counts
        pid, home = self._pid_error, self._home_raw
        skip_p, fail_p, sigma = self._isr_skip_prob, self._enc_fail_prob, self._noise_counts
        mag, h1, h2 = self._magnet_offset, self._harmonic1_counts, self._harmonic2_counts
        p1, p2 = self._harmonic1_phase, self._harmonic2_phase
        cpu, upc = self._counts_per_ustep, self._usteps_per_count
        calibrated = self._encoder_table is not None
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
                va = self._run_accel
                visc = self._rotor_damping_rate
            else:
                since += T
                if since < _POWERDOWN_S:
                    va = self._run_accel
                    visc = self._rotor_damping_rate
                else:
                    va = self._hold_accel
                    visc = self._hold_damping_rate
            field += dx
            vf = self._field_dir * dx / T
            # Mechanics: skipped while everything and the field rest, held by friction.
            moving = W != 0.0 or V != 0.0 or vf != 0.0
            if not moving:
                x = L if has_load else R
                wall = khi * (x - hi) if x > hi else (klo * (x - lo) if x < lo else 0.0)
                net = va * sin(_KE * (F - R))
                if has_load:
                    d = R - L
                    tw = d - gap if d > gap else (d + gap if d < -gap else 0.0)
                    net -= k_rotor * tw
                    net_l = k_load * tw - load - wall
                else:
                    net -= load + wall
                    net_l = 0.0
                moving = not (-fric <= net <= fric and -fric_load <= net_l <= fric_load)
            if moving:
                n = self._min_substeps + int(abs(vf - W) * T / _SLIP_PER_SUBSTEP)
                if n < self._coupling_substeps:
                    n = self._coupling_substeps
                x, v = (L, V) if has_load else (R, W)
                reach = (abs(v) + abs(vf)) * T + _WALL_MARGIN
                if hi - x < reach and n < self._substeps_high_wall:
                    n = self._substeps_high_wall
                if x - lo < reach and n < self._substeps_low_wall:
                    n = self._substeps_low_wall
                h = T / n
                hh = h * h
                hv = 0.5 * h
                fric_h = fric * h
                fric_load_h = fric_load * h
                df = vf * h
                for _ in range(n):
                    ar = va * sin(_KE * (F - R)) / (1.0 + abs(W) * emf)
                    if has_load:
                        # The coupling spring explicit (symplectic Euler: no numerical damping,
                        # stable by the sub-steps), its damper and the viscous terms by the
                        # trapezoidal rule (no numerical damping either), the walls implicit
                        # (backward Euler: stable at any stiffness): a 2x2 solve for W and V.
                        a11 = 1.0 + hv * visc
                        a22 = 1.0 + hv * visc_load
                        a12 = a21 = 0.0
                        b1 = W * (1.0 - hv * visc) + h * ar
                        b2 = V * (1.0 - hv * visc_load) - h * load
                        d = R - L
                        if d > gap or d < -gap:
                            tw = d - gap if d > gap else d + gap
                            sr = hv * c_rotor
                            sl = hv * c_load
                            a11 += sr
                            a22 += sl
                            a12 = -sr
                            a21 = -sl
                            b1 -= h * k_rotor * tw + sr * (W - V)
                            b2 += h * k_load * tw + sl * (W - V)
                        if L > hi:
                            b2 -= h * khi * (L - hi)
                            a22 += hh * khi + (h * chi if V > 0.0 else 0.0)
                        elif L < lo:
                            b2 -= h * klo * (L - lo)
                            a22 += hh * klo + (h * clo if V < 0.0 else 0.0)
                        det = a11 * a22 - a12 * a21
                        W = (b1 * a22 - a12 * b2) / det
                        V = (a11 * b2 - a21 * b1) / det
                        if V > fric_load_h:
                            V -= fric_load_h
                        elif V < -fric_load_h:
                            V += fric_load_h
                        else:
                            V = 0.0
                    else:
                        # Viscous term trapezoidal, wall implicit, on the rotor alone.
                        b1 = W * (1.0 - hv * visc) + h * (ar - load)
                        a11 = 1.0 + hv * visc
                        if R > hi:
                            b1 -= h * khi * (R - hi)
                            a11 += hh * khi + (h * chi if W > 0.0 else 0.0)
                        elif R < lo:
                            b1 -= h * klo * (R - lo)
                            a11 += hh * klo + (h * clo if W < 0.0 else 0.0)
                        W = b1 / a11
                    if W > fric_h:
                        W -= fric_h
                    elif W < -fric_h:
                        W += fric_h
                    else:
                        W = 0.0
                    R += W * h
                    L += V * h
                    F += df
                if not has_load:
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
                counts = (self._corrected(floor(c)) if calibrated else floor(c)) - home
                est.update(counts)
            if cl_on:
                meas = int(upc * counts)
                pid = floor(ramp.x + 0.5) - meas
                if pid >= thr or -pid >= thr:
                    ramp.x = float(meas)
                    if ramp.mode == POSITIONING:
                        ramp.xtarget = self._drv_xtarget
        self._t_next = t_next
        self._rotor, self._rotor_speed, self._load_pos, self._load_speed, self._field_angle = R, W, L, V, F
        self._since_step = since
        self._field = field
        self._counts, self._pid_error = counts, pid

    # ---- MotorHAL (enable/disable_closed_loop are MotorHAL's own) -----------------------------
    def set_control_threshold(self, usteps):
        self._control_threshold = float(usteps)

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
        self._field_dir = -self._wiring_sign if inverted else self._wiring_sign

    def angle_moved(self):
        return self._counts * (360.0 / self._counts_per_rev)

    def encoder_zero(self):
        return (self._home_raw % self._encoder_cpr) * (360.0 / self._counts_per_rev)

    def encoder_rpm(self):
        return self._est.value * (60.0 / self._counts_per_rev)

    def driver_rpm(self):
        """True ramp speed (the library's getDriverRPM under-reports by 1.677, not modelled)."""
        return self._ramp.v * (60.0 / _USTEPS_PER_REV)

    def pid_error(self):
        return float(self._pid_error)

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
        return self._rotor / _ANGLE_TO_STEP

    def encoder_error(self, rotor_deg):
        """Degrees by which the firmware's encoder reading (noise left out, its calibration
        applied) differs from the rotor's true angle `rotor_deg`, up to a constant: the error a
        calibration is to remove."""
        r = rotor_deg * _ANGLE_TO_STEP
        true = r * self._counts_per_ustep + self._magnet_offset
        return (self._corrected(math.floor(self._noise_free(r))) - true) * (360.0 / self._counts_per_rev)

    def slipped_periods(self):
        """Whole electrical periods (4 full steps) the rotor has fallen behind or run ahead of the
        coil field since construction: nonzero once the motor has lost steps."""
        return int(math.floor((self._field_angle - self._rotor) / 1024.0 + 0.5))

    def load_angle(self):
        return (self._load_pos if self._has_load else self._rotor) / _ANGLE_TO_STEP

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
        x, v = (self._load_pos, self._load_speed) if self._has_load else (self._rotor, self._rotor_speed)
        if abs(v) < 1.0:
            v = self._field_dir * self._ramp.v
        self._add(x, -1 if v < 0.0 else 1, stiffness, damping)

    def weaken_magnet(self, noise_factor=20.0, harmonics_deg=(20.0, 10.0), reports=MAGNET_WEAK):
        cpd = self._counts_per_rev / 360.0
        self._noise_counts *= noise_factor
        self._harmonic1_counts = harmonics_deg[0] * cpd
        self._harmonic2_counts = harmonics_deg[1] * cpd
        self._magnet = reports

    def magnet(self):
        return self._magnet

    def set_load_torque(self, nm):
        self._external_torque_nm = nm
        self._load_torque_accel = self._load_accel_per_nm * (self._load_torque_nm + nm)

    def _add(self, at, direction, stiffness, damping):
        k, c = self._end_stop_rates
        if stiffness is not None:
            k = stiffness / self._load_inertia
        if damping is not None:
            c = damping / self._load_inertia
        self._obstacles.append((at, 1 if direction > 0 else -1, k, c))
        self._walls()

    def _walls(self):
        """The tightest wall on each side, with its stiffness and damping (load accel units)."""
        lo, hi = self._stops
        wlo = whi = self._end_stop_rates
        for at, direction, k, c in self._obstacles:
            if direction > 0:
                if at < hi:
                    hi, whi = at, (k, c)
            elif at > lo:
                lo, wlo = at, (k, c)
        self._low_wall, self._high_wall = lo, hi
        self._low_wall_rates, self._high_wall_rates = wlo, whi
        # Implicit walls are stable at any stiffness; sub-steps only resolve the impact.
        self._substeps_low_wall = min(_MAX_WALL_SUBSTEPS, 1 + int(_T_ISR * math.sqrt(wlo[0]) / _WN_H_CPL))
        self._substeps_high_wall = min(_MAX_WALL_SUBSTEPS, 1 + int(_T_ISR * math.sqrt(whi[0]) / _WN_H_CPL))
