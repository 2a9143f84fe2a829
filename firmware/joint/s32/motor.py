"""S32Stepper: the MotorHAL on the uStepper S32, whose TMC5130 generates the ramp itself.

The main loop only sets targets and watches: update() reads the encoder and the driver's XACTUAL,
VACTUAL and status, runs the library's velocity estimator and, with the closed loop on, does what
its 1.54 kHz interrupt did (ustepper-model.md section 3.3): when the driver position and the
encoder disagree by the control threshold or more, XACTUAL is overwritten with the encoder's
position and XTARGET re-issued, so the ramp generator makes up the lost steps.

Differences from the library that the tuning must allow for: the closed loop runs at the main-loop
rate (about 1 kHz, not 1541.85 Hz), so a stalled motor's error baseline v * T is 1.54x larger; and
driver_rpm() reports the true ramp speed (the library reported 0.596x of it).
"""

from ..motion.hal import MAGNET_MISSING, MAGNET_OK, MotorHAL
from ..motion.velocity import FixedVelocityEstimator
from . import tmc5130 as tmc
from .tle5012b import COUNTS_PER_REV

_HALF_REV = COUNTS_PER_REV // 2
_LIMIT = 0x3FFFFFFF
_Q4_CAP = 20000 * 16  # full steps/s(^2) in Q4 beyond every driver limit


class S32Stepper(MotorHAL):
    """The library's behaviour on a TMC5130 and a TLE5012B (tmc5130.TMC5130, tle5012b.TLE5012B or
    fakes), `enable` the driver's enable pin (low = on), `rate_hz` the update() rate."""

    _encoder_cpr = COUNTS_PER_REV

    def __init__(self, driver, encoder, enable=None, rate_hz=1000):
        self._drv = driver
        self._enc = encoder
        self._enable = enable
        self._vel = FixedVelocityEstimator(rate_hz)
        self._vs = self._vel.s
        self._ready = False
        self._closed_loop = False
        self._threshold = 10
        self._error = 0
        self._raw = 0  # last encoder angle (15 bits) and the count unwrapped from it
        self._count = 0
        self._offset = 0  # raw angle at home
        self._x = 0  # XACTUAL, VACTUAL and the SPI status of the last update
        self._v = 0
        self._status = 0
        self._field_offset = 0  # usteps the closed loop relabelled: field = XACTUAL + offset
        self._mode = tmc.POSITIONING
        self._target = 0  # XTARGET as last written (the library's xTarget shadow)
        self._vmax = self._amax = self._dmax = 0
        self._stopping = False
        self._irun = self._ihold = 0
        self._gconf = tmc.GCONF_BASE
        self.faults = 0

    # ---- setup ----

    def begin(self):
        """setup(CLOSEDLOOP, 200): the driver checked and configured as the library does, positions
        zeroed, 40 %/40 % current (the library's setup default is 50/30; the joint sets its own),
        closed loop inactive. Raises tmc.TMCError when no TMC5130 answers, OSError when the
        encoder does not."""
        drv = self._drv
        if self._enable is not None:
            self._enable(0)
        drv.check()
        for reg, value in ((tmc.GCONF, self._gconf), (tmc.CHOPCONF, tmc.CHOPCONF_BASE),
                           (tmc.PWMCONF, tmc.PWMCONF_BASE), (tmc.TPWMTHRS, 5000), (tmc.TPOWERDOWN, 10),
                           (tmc.VSTART, 0), (tmc.A1, 0), (tmc.V1, 0), (tmc.D1, tmc.AMAX_LIMIT),
                           (tmc.VSTOP, tmc.VSTOP_MIN), (tmc.AMAX, tmc.AMAX_LIMIT), (tmc.DMAX, tmc.AMAX_LIMIT),
                           (tmc.VMAX, 0), (tmc.RAMPMODE, tmc.POSITIONING), (tmc.XACTUAL, 0),
                           (tmc.XTARGET, 0)):
            drv.write(reg, value)
        self._amax = self._dmax = tmc.AMAX_LIMIT
        self.set_current(40)
        self.set_hold_current(40)
        raw = self._enc.read_angle()
        if raw < 0:
            raise OSError("TLE5012B encoder: no valid angle (safety word 0x%04x)" % self._enc.safety)
        self._offset = self._corrected(raw)
        self._raw = 0
        self._count = 0
        self._vel.reset()
        self._ready = True

    # ---- once per main-loop iteration ----

    def update(self):
        """Encoder sample, driver position and speed, velocity estimate, closed-loop resync;
        allocation-free (ints below 2**30 only)."""
        if not self._ready:
            return
        drv = self._drv
        raw = self._enc.read_angle()
        if raw >= 0:
            raw = (self._corrected(raw) - self._offset) & 0x7FFF
            delta = raw - self._raw
            if delta > _HALF_REV:
                delta -= COUNTS_PER_REV
            elif delta < -_HALF_REV:
                delta += COUNTS_PER_REV
            self._raw = raw
            self._count += delta
            self._vel.update(self._count)
        drv.frame(tmc.XACTUAL, 0)  # each frame brings the previous request's register
        x = drv.frame(tmc.VACTUAL, 0)
        self._x = x
        self._v = tmc.signed24(drv.frame(tmc.VACTUAL, 0))
        self._status = drv.status
        if self._closed_loop and raw >= 0:
            count = self._count
            measured = (count * 25) >> 4 if count >= 0 else -((-count * 25) >> 4)  # 1.5625 a count
            error = x - measured
            self._error = error
            if error >= self._threshold or -error >= self._threshold:
                drv.write(tmc.XACTUAL, measured)
                self._x = measured
                self._field_offset += error
                if self._mode == tmc.POSITIONING:
                    drv.write(tmc.XTARGET, self._target)
        if self._stopping and self._v == 0:
            self._finish_stop()

    # ---- motion (the TMC5130's ramp generator) ----

    def set_max_velocity(self, full_steps_per_s):
        """Full steps/s in Q4; applies to a running positioning ramp, as the library's does."""
        fs = abs(full_steps_per_s)
        self._vmax = tmc.vmax_of_fs_q4(fs if fs < _Q4_CAP else _Q4_CAP)
        if not self._stopping and self._mode == tmc.POSITIONING:
            self._drv.write(tmc.VMAX, self._vmax)

    def set_max_acceleration(self, full_steps_per_s2):
        a = abs(full_steps_per_s2)
        self._amax = tmc.amax_of_fs_q4(a if a < _Q4_CAP else _Q4_CAP)
        if not self._stopping:
            self._drv.write(tmc.AMAX, self._amax)

    def set_max_deceleration(self, full_steps_per_s2):
        a = abs(full_steps_per_s2)
        self._dmax = tmc.amax_of_fs_q4(a if a < _Q4_CAP else _Q4_CAP)
        if not self._stopping:
            self._drv.write(tmc.DMAX, self._dmax)

    def set_rpm(self, rpm):
        """Velocity mode at `rpm` (Q16; the sign is the direction, 0 ramps down with AMAX)."""
        drv = self._drv
        if self._stopping:  # a new command ends a stop (the library's stop() blocks instead)
            self._stopping = False
            drv.write(tmc.AMAX, self._amax)
        drv.write(tmc.VMAX, tmc.vmax_of_rpm_q16(rpm))
        mode = tmc.VELOCITY_POS if rpm > 0 else tmc.VELOCITY_NEG
        if mode != self._mode:
            drv.write(tmc.RAMPMODE, mode)
            self._mode = mode

    def _position(self, target):
        """Positioning mode to XTARGET `target` with the stored speed and accelerations."""
        drv = self._drv
        self._stopping = False
        drv.write(tmc.AMAX, self._amax)
        drv.write(tmc.DMAX, self._dmax)
        drv.write(tmc.VMAX, self._vmax)
        drv.write(tmc.XTARGET, target)
        self._target = target
        self._status = 0  # position_reached waits for a status read after the new target
        if self._mode != tmc.POSITIONING:
            drv.write(tmc.RAMPMODE, tmc.POSITIONING)
            self._mode = tmc.POSITIONING

    def move_steps(self, usteps):
        """Positioning relative to XACTUAL (read now, as the library's moveSteps does)."""
        self._position(self._drv.read(tmc.XACTUAL) + usteps)

    def move_angle(self, degrees):
        """Relative move of `degrees` in Q12, rounded to usteps half away from 0 (x 51200 / 360)."""
        self.move_steps(_usteps(degrees))

    def move_to_angle(self, degrees):
        """Absolute move to `degrees` (Q12) of encoder angle since home."""
        self.move_steps(_usteps(degrees - self.angle_moved()))

    def stop(self, hard=True):
        """Velocity 0 at AMAX (soft) or the driver's maximum (hard); at standstill update() holds
        the position in positioning mode with VMAX 0, as the library's stop() leaves it."""
        drv = self._drv
        self._stopping = True
        if hard:
            drv.write(tmc.AMAX, tmc.AMAX_LIMIT)
        drv.write(tmc.VMAX, 0)
        if self._mode == tmc.POSITIONING:
            drv.write(tmc.RAMPMODE, tmc.VELOCITY_POS)
            self._mode = tmc.VELOCITY_POS
        if self._v == 0:
            self._finish_stop()

    def _finish_stop(self):
        drv = self._drv
        self._stopping = False
        x = drv.read(tmc.XACTUAL)
        self._x = x
        drv.write(tmc.XTARGET, x)
        self._target = x
        drv.write(tmc.RAMPMODE, tmc.POSITIONING)
        self._mode = tmc.POSITIONING
        drv.write(tmc.AMAX, self._amax)

    # ---- driver settings ----

    def _currents(self):
        self._drv.write(tmc.IHOLD_IRUN, tmc.ihold_irun(self._ihold, self._irun))

    def set_current(self, percent):
        self._irun = tmc.percent_to_cs(percent)
        self._currents()

    def set_hold_current(self, percent):
        self._ihold = tmc.percent_to_cs(percent)
        self._currents()

    def set_brake_mode(self, mode):
        """0 freewheel (coils open), 1 coolbrake (coils shorted), 2 hardbrake (25 % holding
        current, the library's default brake current); the first two need IHOLD 0."""
        freewheel = 1 if mode == 0 else (2 if mode == 1 else 0)
        self._ihold = tmc.percent_to_cs(25) if mode == 2 else 0
        self._drv.write(tmc.PWMCONF, tmc.PWMCONF_BASE | (freewheel << tmc.FREEWHEEL_SHIFT))
        self._currents()

    def set_inverted(self, inverted):
        self._gconf = tmc.GCONF_BASE | (tmc.SHAFT if inverted else 0)
        self._drv.write(tmc.GCONF, self._gconf)

    def set_home(self):
        """encoder.setHome() and driver.setHome(): both read 0 here; a positioning move keeps its
        remaining distance, otherwise the target becomes 0 too."""
        drv = self._drv
        raw = self._enc.read_angle()
        if raw >= 0:
            self._offset = self._corrected(raw)
        self._raw = 0
        self._count = 0
        self._vel.reset()
        x = drv.read(tmc.XACTUAL)
        self._field_offset += x
        self._target = self._target - x if self._mode == tmc.POSITIONING else 0
        drv.write(tmc.XACTUAL, 0)
        drv.write(tmc.XTARGET, self._target)
        self._x = 0

    # ---- getters ----

    def angle_moved(self):
        """Encoder angle since home, degrees Q12: 45 Q12 units a count (360 * 4096 / 32768)."""
        count = self._count
        return count * 45 if -23860929 < count < 23860929 else (_LIMIT if count > 0 else -_LIMIT)

    def encoder_zero(self):
        return (self._offset & 0x7FFF) * 45

    def encoder_rpm(self):
        """rpm Q16 from the estimator's counts/s (Q8): x 60 / 32768 x 65536 / 256 = x 15 / 32."""
        return (self._vs[6] * 15) >> 5

    def driver_rpm(self):
        return tmc.rpm_q16_of_vactual(self._v)

    def pid_error(self):
        return self._error

    def position_reached(self):
        return (not self._stopping and self._mode == tmc.POSITIONING
                and self._status & tmc.POSITION_REACHED != 0)

    def field_position(self):
        """XACTUAL plus every relabel of the closed loop and set_home, wrapping at 2**30."""
        return (self._x + self._field_offset) & _LIMIT

    def driver_position(self):
        return self._x

    def magnet(self):
        """One angle read: a reading the TLE5012B's safety word flags (system error, access error,
        invalid angle) or a wrong CRC counts as no magnet. The safety word does not tell a weak
        magnet from a strong one and its STAT register is not read: a marginal magnet meets the
        homing's noise check."""
        return MAGNET_MISSING if self._enc.read_angle() < 0 else MAGNET_OK

    def diagnostics(self):
        """Driver and encoder health (reads the driver; for the debug console, not the loop)."""
        drv = self._drv
        drv.read(tmc.DRV_STATUS)
        top = drv.rx[1]
        return {"encoder_errors": self._enc.errors, "encoder_safety": self._enc.safety,
                "standstill": bool(top & 0x80), "open_load": bool(top & 0x60),
                "short_to_ground": bool(top & 0x18), "overtemperature": bool(top & 0x06),
                "stall_guard": bool(top & 0x01)}


def _usteps(degrees):
    """Motor degrees (Q12) to usteps, half away from 0: x 51200 / 360 / 4096 = x 5 / 144."""
    a = degrees if degrees >= 0 else -degrees
    q = a // 144
    steps = (q * 10 + (a - q * 144) * 10 // 144 + 1) >> 1
    return steps if degrees >= 0 else -steps
