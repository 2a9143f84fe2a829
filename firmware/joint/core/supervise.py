"""The joint core's supervision: stall detection and the deadman, run by the main loop (what
the joint's state refuses, the IRQ path decides: irq.py).

Deadman. A freshly booted joint keeps the original's: more than `deadman_ms` (50) without a
transaction while the velocity setpoint is not 0 stops it, so original-host programs that poll at
10 Hz during position moves keep working. Once a host writes WATCHDOG (ours does when it configures
a joint) its timeout covers every motion mode: velocity, positioning, homing, orientation check.
Either way the flags do not matter (a joint whose current or closed loop was turned off still
turns), the stop starts on the first main-loop tick after the timeout and brakes at the per-joint
`stop_deceleration` (the fastest stop that keeps position, not the host's slow acceleration), then
takes the per-joint `safe_action`: hold at the hold current, or freewheel.

Stall detection. `stall.detector` picks the original (stall.py, filtered |PID error|) or the
tracking detector (tracking.py, the encoder no longer following the field);
`set_stall_detector()` switches at run time (bench, tests).
"""

from ..micro import const, micropython
from ..motion.fixed import muldiv
from .irq import FTAB_REARMS
from ..spec.protocol import FLAG_BUSY, FLAG_NOTENABLED, FLAG_NOTHOMED, FLAG_STALL


HOLD_WINDOW = const(15 << 12)  # motor degrees Q12: within this of its target a move has arrived ...
HOLD_RPM = const(30 << 16)  # ... once its driver turns slower than this (rpm Q16)
ORIGINAL = const(0)
TRACKING = const(1)
DETECTOR_NAMES = ("original", "tracking")


class Supervisor:
    """JointController's supervision (mixed into it)."""

    def set_stall_detector(self, name):
        """Select the stall detector by name ("original" or "tracking")."""
        self.detector = DETECTOR_NAMES.index(name)
        self.stall.reset()
        self._forget_motion()

    def _forget_motion(self):
        """The tracking and slow-contact detectors start afresh (a stop, a re-arm, a re-zero)."""
        self.track.reset()
        if self.load is not None:
            self.load.reset()

    def _encoder_usteps(self):
        """The encoder angle in usteps (int): degrees Q12 x 51200 / 360 / 4096 = 5 / 144, exact on
        the Pico, where the angle is AS5600 counts x 360."""
        a = self.hal.angle_moved()
        if a >= 0:
            return muldiv(a, 5, 144)
        return -muldiv(-a, 5, 144)

    def _host_angle(self):
        """The angle the host sees (ANGLEMOVED, MOVETOANGLE), degrees Q12: 0 at the end stop
        homing found."""
        return self.hal.angle_moved() + self.zero_offset

    # ---- main loop, every iteration: no allocation ----

    def _check_stall(self):
        """The original detector, every stall.sample_time."""
        if self.detector != ORIGINAL or not self.stallguard or self.flags & (FLAG_STALL | FLAG_BUSY):
            return
        hal = self.hal
        rearms = self._ftab[FTAB_REARMS]
        stalled = self.stall.update(hal.pid_error(), hal.encoder_rpm(), self.qd_set)
        if self.trace is not None:
            self.trace(self.stall)
        if stalled and self._halt(FLAG_STALL, rearms=rearms):
            hal.stop(True)
            self.log.warn("stall detected (filtered error %.1f > threshold %.1f)"
                          % (self.stall.filtered, self.stall.threshold))

    def _check_tracking(self):
        """The tracking detector and, where configured, the slow-contact one (load_angle.py),
        every stall.track_sample_ms."""
        track = self.track
        load = self.load
        if self.detector != TRACKING or not self.stallguard or self.flags & (FLAG_STALL | FLAG_BUSY):
            self._forget_motion()
            return
        hal = self.hal
        rearms = self._ftab[FTAB_REARMS]
        field = hal.field_position()
        encoder = self._encoder_usteps()
        if track.update(field, encoder) and self._halt(FLAG_STALL, rearms=rearms):
            hal.stop(True)
            self.log.warn("stall detected (encoder %d usteps behind the field, threshold %d)"
                          % (track.lag, track.threshold))
            track.reset()
        elif load is not None and load.update(field, encoder, hal.driver_rpm()) and self._halt(
                FLAG_STALL, rearms=rearms):
            hal.stop(True)
            self.log.warn("contact detected (load angle %d usteps over its free-running one, limit %d)"
                          % (load.excess, load.limit))
            load.reset()

    def _motion_active(self):
        """What the deadman guards: in watchdog mode every motion the host commanded, and the ramp
        after it until the motor first stands; at boot the velocity setpoint. A move to an angle
        has arrived once it is within HOLD_WINDOW of its target turning slower than HOLD_RPM; from
        then on it holds there, whatever speed its closed loop corrects at (a re-synchronisation
        runs at the host's acceleration), until it leaves the window: a quiet host never gets a
        joint disabled that holds its target, and one still travelling toward it is stopped."""
        if not self.watchdog_ms:
            return self.qd_set != 0
        if self.qd_set != 0 or (self._task is not None and self.task_name != "boot"):
            self._coasting = True
            self._arrived = False
            return True
        if (self.positioning or self._coasting) and self.target_known:
            if abs(self.q_set - self._host_angle()) > HOLD_WINDOW:
                self._arrived = False  # not there yet, or pushed away: travelling
            elif self._arrived or abs(self.hal.driver_rpm()) < HOLD_RPM:
                self._arrived = True
                self._coasting = False
                return False
        if self.positioning:
            self._coasting = True
            return True
        if self._coasting and self.hal.driver_rpm() != 0:
            return True
        self._coasting = False
        return False

    @micropython.native
    def _check_deadman(self):
        if self._safe_pending:  # this deadman's quick stop is braking: decided once, not per tick
            self._safe_action()
            return
        timeout = self.watchdog_ms
        if timeout:
            if not self._motion_active():
                return
        elif self.qd_set == 0:  # the original's deadman: the velocity setpoint only
            return
        else:
            timeout = self._deadman_ms
        clock = self.clock
        seen = self.transactions  # before the stamp: a transaction after it refuses the halt
        silent = clock.ticks_diff(clock.ticks_us(), self.host_us) // 1000  # from the IRQ's stamp
        if silent < timeout or not self._halt(FLAG_NOTENABLED, transactions=seen):
            return
        task = self.task_name
        if self._task is not None and task != "boot":
            self._abort_task()
        self._quick_stop()
        self._safe_pending = True
        self.log.warn("deadman: no I2C traffic for %d ms, motor stopped and disabled%s"
                      % (silent, "" if task is None else " (%s aborted)" % task))

    def _abort_task(self):
        """End HOME or CHECKORIENTATION where it is, leaving the driver as it was before."""
        homing = self.task_name == "HOME"
        self._task.close()
        self._end_task()
        hal = self.hal
        hal.set_inverted(self.inverted)
        if self.closed_loop:
            hal.enable_closed_loop()
        hal.set_current(self.drive_current)
        hal.set_hold_current(self.hold_current)
        if homing:
            self._set_flags(FLAG_NOTHOMED)

    def _quick_stop(self):
        """Brake at stop_deceleration; the host's limits apply again once the motor stands."""
        hal = self.hal
        decel = self.stop_deceleration
        hal.set_max_acceleration(decel)
        hal.set_max_deceleration(decel)
        hal.stop(False)
        hal.set_max_acceleration(self.max_acceleration)
        hal.set_max_deceleration(self.max_deceleration)
        self.qd_set = 0
        self.positioning = False

    def _safe_action(self):
        """After a deadman stop, once the motor stands: hold (nothing to do) or freewheel."""
        if self.hal.driver_rpm() != 0:
            return
        self._safe_pending = False
        if self.cfg.safe_action == "freewheel":
            hal = self.hal
            hal.set_hold_current(0)
            hal.set_current(0)
            hal.set_brake_mode(0)
