"""PicoStepper: the MotorHAL on a Raspberry Pi Pico, a TMC2209 and an AS5600.

The TMC5130 of the uStepper generated its own ramp; here joint.motion.tickramp.TickRamp plays that part in the
main loop and the PIO turns it into STEP/DIR pulses (stepgen.py). update() does what the
library's 1.54 kHz timer interrupt did (ustepper-model.md section 3): sample the encoder, run the
velocity estimator and, with the closed loop on, re-synchronise the driver position to the encoder
whenever they disagree by the control threshold or more. Then it advances the ramp and queues the
next burst of pulses.

Differences from the uStepper that the stall and homing tuning must allow for:
* the closed loop runs at the main-loop rate (`update_hz`, default 1 kHz) instead of 1541.85 Hz,
  so a stalled motor's error baseline, v * T, is 1.54x larger at the same speed;
* the AS5600 has 4096 counts/rev, 12.5 usteps per count, so the PID error has a 12.5-ustep
  quantum plus about a count of noise; a control threshold below ~2.5 counts (31 usteps) makes
  the loop chase that noise at standstill (the original firmware boots with 15);
* the encoder's filter lag (config encoder_slow_filter) adds v * lag to the error at speed;
* driver_rpm() reports the true ramp speed (the library reported 0.596x of it).

Default wiring (motor_config.DEFAULT_PINS; the joint bus target is I2C0 on GP4 SDA / GP5 SCL):

    UART1 TX GP8 --1k--+-- TMC2209 PDN_UART      I2C1 SDA GP6 -- AS5600 SDA
    UART1 RX GP9 ------+                          I2C1 SCL GP7 -- AS5600 SCL (pull-ups on the board)
    GP10 -- STEP    GP11 -- DIR    GP12 -- EN (low = enabled)
    TMC2209 MS1/MS2 set the UART node address (tmc_address); SPREAD tied low.
"""

from ..micro import const, micropython, ptr32

from ..motion.fixed import muldiv
from ..motion.hal import MAGNET_MISSING, MotorHAL
from ..motion.tickramp import POSITIONING, VELOCITY_NEG, run_ramp
from ..motion.velocity import update_velocity
from . import tmc2209 as tmc
from .as5600 import decode_status, magnet_health
from .as5600 import next_sample as _enc_next
from .stepgen import issue_steps, poll_steps


_FS_Q4_CAP = 20000 * 16  # full steps/s(^2) in Q4 beyond every limit below: keeps products small
_MAX_DT_TICKS = const(4)  # a late update advances the ramp by at most this many loop periods


# Words of the state arrays _resync and the 1 kHz methods work on, as constants here (viper
# needs them; elsewhere each saves a global lookup): the encoder's (as5600.S_RAW, S_COUNT, S_AT,
# S_NEXT) and the ramp's position and speed (tickramp.S_X, S_V); test_pico_motor checks.
_ES_RAW = const(0)
_ES_COUNT = const(1)
_ES_AT = const(4)
_ES_NEXT = const(6)
_RS_X = const(0)
_RS_V = const(2)
_LIMIT = const(0x3FFFFFFF)  # fixed.LIMIT


@micropython.viper
def _resync(es: ptr32, ss: ptr32, rs: ptr32, threshold: int) -> int:
    """The closed loop's tick: the PID error (usteps, the driver position when the encoder was
    read minus the encoder's), and when |error| >= threshold the driver frame shifted onto the
    encoder (_relabel(-error): step generator, ramp, and the queued read's tag). Words are read
    sign-extended as in tickramp.run_ramp."""
    m = 1
    m <<= 31
    k = m + m - 1
    count = ((es[_ES_COUNT] + m) & k) - m
    measured = (count * 25) >> 1 if count >= 0 else 0 - (((0 - count) * 25) >> 1)  # 12.5 a count
    error = ((es[_ES_AT] + m) & k) - m - measured
    if error >= threshold or 0 - error >= threshold:
        ss[0] = ss[0] - error  # position and commanded: wrap-around arithmetic, any port
        ss[1] = ss[1] - error
        rs[_RS_X] = rs[_RS_X] - error
        es[_ES_NEXT] = es[_ES_NEXT] - error
    return error


_RS_MODE = const(3)  # tickramp.S_MODE, S_VMAX, VELOCITY_POS, VELOCITY_NEG
_RS_VMAX = const(5)
_VELOCITY_POS = const(1)
_VELOCITY_NEG = const(2)


@micropython.viper
def _velocity_mode(rs: ptr32, rpm: int, den: int, limit: int):
    """Ramp words for velocity mode at `rpm` (Q16): VMAX = muldiv(|rpm|, 2560, den) in Q16
    usteps/tick (den = 3 * rate: 51200 / 60 usteps/s per rpm), at most `limit`; the direction
    from the sign (0 ramps down)."""
    a = rpm if rpm >= 0 else 0 - rpm
    q = a // den
    if q > limit // 2560:
        v = limit  # beyond the limit, and q * 2560 could overflow a word
    else:
        v = q * 2560 + (a - q * den) * 2560 // den
        if v > limit:
            v = limit
    rs[_RS_VMAX] = v
    rs[_RS_MODE] = _VELOCITY_POS if rpm > 0 else _VELOCITY_NEG


class PicoStepper(MotorHAL):
    """The uStepper library's behaviour on Pico hardware objects passed in (fakes in tests)."""

    _encoder_cpr = 4096  # AS5600 counts per turn (begin() sets _encoder_error, the calibrated error
    # at the last reading, which the count already has taken off)

    def __init__(self, driver, encoder, steps, enable=None, clock=None, update_hz=1000,
                 rsense_ohm=0.11, full_scale_ma=1500, encoder_slow_filter=3, encoder_fast_threshold=0):
        from .motor_config import init_stepper  # boot only: app drops it after
        init_stepper(self, driver, encoder, steps, enable, clock, update_hz, rsense_ohm, full_scale_ma,
                     encoder_slow_filter, encoder_fast_threshold)

    @classmethod
    def from_config(cls, motor_cfg, clock=None):
        """Build the real objects from a motor config dict (DEFAULTS fill the gaps)."""
        from .motor_config import build_stepper  # boot only: app drops it after
        return build_stepper(cls, motor_cfg, clock)

    # ---- setup ----

    def begin(self):
        """setup(CLOSEDLOOP, 200): driver and encoder configured, encoder and driver zeroed,
        40 %/40 % current, closed loop inactive. Raises OSError (TMCError) on a hardware fault."""
        from .motor_config import begin_stepper  # boot only: app drops it after the boot task
        begin_stepper(self)

    # ---- the timer interrupt of the library, once per main-loop iteration ----

    def _v(self, usteps_per_s):
        """usteps/s -> the ramp's Q16 usteps per tick (configuration time: may allocate)."""
        return int(abs(usteps_per_s) * self._per_tick + 0.5)

    def _a(self, usteps_per_s2):
        return int(abs(usteps_per_s2) * self._per_tick2 + 0.5)

    @micropython.native
    def update(self):
        """One control period: allocation-free (integers only), see the module docstring. The
        ramp, the velocity estimator and the pulse bookkeeping are viper functions over their
        int32 state arrays: a few calls instead of a hundred attribute loads."""
        if not self._ready:
            return
        ss, sm, pio, rs, es, enc_regs, enc_buf, vs, ticks_us, diff, add, tick_us = self._hot
        now = ticks_us()
        # The nearest whole number of periods: the period grid starts at a call (the resync
        # below), so a call late or early by less than half a period neither skips a period nor
        # runs two at once.
        ticks = (diff(now, self._last_us) + (tick_us >> 1)) // tick_us
        if ticks <= 0:
            return  # called again within the same period
        if ticks > _MAX_DT_TICKS:
            ticks = _MAX_DT_TICKS
            self._last_us = now
        else:
            self._last_us = add(self._last_us, ticks * tick_us)  # wraps as ticks_us does: a small int
        poll_steps(ss, sm, pio)
        # The encoder read queued at the last update, tagged with the driver and field positions
        # of that instant (as5600.py); a blocking read when none is queued.
        got = _enc_next(es, enc_regs, enc_buf, ss[0], ss[3])
        if got < 0:
            got = self._enc.sample(ss[0], ss[3])
        if got:
            if self._encoder_table is not None:
                # The count unwraps raw readings (as5600.next_sample): it moves by the change of the error.
                raw = es[_ES_RAW]
                error = raw - self._corrected(raw)
                es[_ES_COUNT] += self._encoder_error - error
                self._encoder_error = error
            update_velocity(vs, es[_ES_COUNT])
            if self._closed_loop:
                self._error = _resync(es, ss, rs, self._threshold)
        run_ramp(rs, ticks)
        if self._stopping and rs[_RS_V] == 0:
            self._finish_stop()
        issue_steps(ss, sm, pio, rs[_RS_X], ticks * tick_us)

    def _relabel(self, delta):
        """Shift the driver frame by `delta` usteps without moving the motor (an XACTUAL write):
        in positioning mode the ramp then makes up the difference toward the same target."""
        self._steps.shift(delta)
        self._ramp.x += delta  # keeps the sub-ustep fraction
        self._es[_ES_NEXT] += delta  # the queued encoder read's driver position

    # ---- motion ----

    # Like the library these apply to the running ramp at once, except during a stop, which
    # the library finishes (blocking) before anything else runs; it restores them at the end.

    def set_max_velocity(self, full_steps_per_s):
        """Full steps/s in Q4 (fixed.STEPS_Q)."""
        fs = abs(full_steps_per_s)
        fs = fs if fs < _FS_Q4_CAP else _FS_Q4_CAP
        v = muldiv(fs * 64, 16384, self._rate)  # Q4 fs/s -> Q16 usteps/tick
        self._vmax = v if v < self._vmax_limit else self._vmax_limit
        if not self._stopping:
            self._ramp.vmax = self._vmax

    def _accel(self, q4):
        """Full steps/s^2 in Q4 -> Q16 usteps/tick^2, clamped to the driver's maximum."""
        rate = self._rate
        q4 = abs(q4)
        a = muldiv(muldiv(q4 if q4 < _FS_Q4_CAP else _FS_Q4_CAP, 1024, rate), 1024, rate)
        return a if a < self._max_accel else self._max_accel

    def set_max_acceleration(self, full_steps_per_s2):
        """Full steps/s^2 in Q4 (fixed.STEPS_Q)."""
        self._amax = self._accel(full_steps_per_s2)
        if not self._stopping:
            self._ramp.amax = self._amax

    def set_max_deceleration(self, full_steps_per_s2):
        self._dmax = self._accel(full_steps_per_s2)
        if not self._stopping:
            self._ramp.dmax = self._dmax

    @micropython.native
    def set_rpm(self, rpm):
        """Velocity mode: VMAX = |rpm| (Q16, fixed.RPM_Q), direction from the sign (0 ramps down)."""
        if self._stopping:  # a new command ends a stop (the library's stop() blocks instead)
            self._stopping = False
            self._ramp.amax = self._amax
            self._ramp.dmax = self._dmax
        _velocity_mode(self._rs, rpm, self._vmax_den, self._vmax_limit)  # a host streams SETRPM

    def move_steps(self, usteps):
        """Positioning to the ramp position + usteps with the stored velocity and accelerations."""
        ramp = self._ramp
        self._stopping = False
        ramp.vmax = self._vmax
        ramp.amax = self._amax
        ramp.dmax = self._dmax
        ramp.mode = POSITIONING
        ramp.xtarget = ramp.xactual() + usteps

    def move_angle(self, degrees):
        """Relative move of `degrees` in Q12 (fixed.ANGLE_Q), rounded to usteps half away from 0."""
        steps = (muldiv(degrees if degrees >= 0 else -degrees, 10, 144) + 1) >> 1  # 51200/360/4096
        self.move_steps(steps if degrees >= 0 else -steps)

    def move_to_angle(self, degrees):
        """Absolute move to `degrees` (Q12) of encoder angle since home."""
        diff = degrees - self.angle_moved()
        steps = (muldiv(diff if diff >= 0 else -diff, 10, 144) + 1) >> 1
        self.move_steps(steps if diff >= 0 else -steps)

    def stop(self, hard=True):
        """setRPM(0) at the current AMAX (soft) or the driver's maximum (hard); when the ramp
        stands still, update() restores AMAX/DMAX and holds the position in positioning mode."""
        ramp = self._ramp
        self._stopping = True
        if hard:
            ramp.amax = self._max_accel
            ramp.dmax = self._max_accel
        ramp.vmax = 0
        ramp.mode = VELOCITY_NEG
        if ramp.v == 0:
            self._finish_stop()

    def _finish_stop(self):
        """setPosition(XACTUAL): hold where the ramp stopped. VMAX stays 0 as in the library, so
        closed-loop corrections do not move the motor until the next motion command."""
        ramp = self._ramp
        self._stopping = False
        ramp.amax = self._amax
        ramp.dmax = self._dmax
        ramp.mode = POSITIONING
        ramp.xtarget = ramp.xactual()
        ramp.set_position(ramp.xtarget)

    # ---- driver settings ----

    def _write(self, reg, value):
        try:
            self._drv.write(reg, value)
        except OSError as exc:
            self.fault = str(exc)
            self.faults += 1

    def set_current(self, percent):
        self._irun = tmc.percent_to_cs(percent, self._cs_max)
        self._write(tmc.IHOLD_IRUN, tmc.ihold_irun(self._ihold, self._irun))

    def set_hold_current(self, percent):
        self._ihold = tmc.percent_to_cs(percent, self._cs_max)
        self._write(tmc.IHOLD_IRUN, tmc.ihold_irun(self._ihold, self._irun))

    def set_brake_mode(self, mode):
        self._ihold, freewheel = tmc.brake_settings(mode, self._cs_max)
        self._pwmconf = tmc.pwmconf(self._pwmconf, freewheel)
        self._write(tmc.PWMCONF, self._pwmconf)
        self._write(tmc.IHOLD_IRUN, tmc.ihold_irun(self._ihold, self._irun))

    def set_inverted(self, inverted):
        self._write(tmc.GCONF, tmc.gconf(inverted))

    def set_home(self):
        """encoder.setHome() and driver.setHome(): both read 0 here; a positioning move keeps
        its remaining distance, otherwise the target becomes 0 too."""
        self._enc.set_home()
        self._vel.reset()
        delta = -self._steps.position
        self._relabel(delta)
        ramp = self._ramp
        if ramp.mode == POSITIONING:
            ramp.xtarget += delta
        else:
            ramp.xtarget = 0

    # ---- getters ----

    def angle_moved(self):
        """Encoder angle since home, degrees in Q12 (exact: 360 Q12 units a count)."""
        count = self._es[_ES_COUNT]
        return count * 360 if -2982616 < count < 2982616 else (_LIMIT if count > 0 else -_LIMIT)

    def encoder_zero(self):
        """The sensor's angle at home, Q12 degrees (360 a count): the last reading less the count."""
        enc = self._enc
        return ((enc.raw - self._encoder_error - enc.count) & 0xFFF) * 360

    def encoder_rpm(self):
        """rpm in Q16: counts/s (Q8) * 60 / 4096 * 256 (|counts/s| < 280 000 keeps it small)."""
        return (self._vs[6] * 15) >> 2  # the estimator's value

    def driver_rpm(self):
        """Speed of the ramp generator, rpm in Q16 (the ramp's Q16 usteps/tick * rate * 60 / 51200),
        rounded toward minus infinity; muldiv inlined (it runs at 1 kHz)."""
        v = self._rs[_RS_V]
        den = self._rpm_den
        q = v // den
        return q * self._rpm_num + (v - q * den) * self._rpm_num // den

    def pid_error(self):
        """usteps (int)."""
        return self._error

    def field_position(self):
        """Usteps of pulses that reached the driver since construction, wrapping at 2**30, when
        the encoder's latest sample was read (with a queued read one period ago): the stall and
        homing evidence compare the two at the same instant."""
        return self._es[_ES_AT + 1]

    def position_reached(self):
        return not self._stopping and self._ramp.position_reached() and self._steps.idle()

    def driver_position(self):
        """Usteps of pulses that have reached the driver (XACTUAL of the uStepper)."""
        return self._steps.position

    def magnet(self):
        """The AS5600's STATUS bits (MD, ML, MH) as a MAGNET_* code; a sensor that does not
        answer reports no magnet. One blocking read: the next sample re-aims the pointer."""
        try:
            return magnet_health(self._enc.status())
        except OSError:
            return MAGNET_MISSING

    def diagnostics(self):
        """Driver and encoder health (reads both buses; for the debug console, not the loop)."""
        detected, weak, strong = decode_status(self._enc.status())
        report = {"magnet_detected": detected, "magnet_too_weak": weak, "magnet_too_strong": strong,
                  "encoder_errors": self._enc.errors, "uart_faults": self.faults, "uart_fault": self.fault}
        report.update(tmc.decode_drv_status(self._drv.read(tmc.DRV_STATUS)))
        return report
