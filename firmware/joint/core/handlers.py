"""The joint core's register handlers: one per command register, run by the main loop.

Each gets the queue and the payload offset of its slot (`loop.py` drains the queue in order).
Float32 payloads are decoded to the HAL's fixed-point units on their bits (`fixed.py`): a host
streaming SETRPM or MOVETOANGLE at its cycle rate creates no float on the board.
"""

import struct

from ..micro import micropython
from ..motion.fixed import ANGLE_Q, RPM_Q, STEPS_Q, f32_to_q, i32, muldiv
from ..spec.protocol import WATCHDOG
from .irq import SLOT_STOPS

_EPOCH = SLOT_STOPS - 1  # from a payload's offset: its slot's stop epoch (a blocking command's)


def _full_steps(q, off):
    """|float32 deg/s (or deg/s^2)| at q[off:] as full steps/s in Q4 (200 full steps a turn)."""
    value = f32_to_q(q, off, STEPS_Q)
    return muldiv(value if value >= 0 else -value, 5, 9)


class Handlers:
    """JointController's register handlers (mixed into it): (queue, payload offset), main loop."""

    def _setup(self, q, off):
        self.drive_current = q[off]
        self.hold_current = q[off + 1]
        self.hal.set_current(self.drive_current)
        self.hal.set_hold_current(self.hold_current)
        self.hal.move_steps(0)
        self.stallguard = False
        self.qd_set = 0
        self.positioning = False
        self._safe_pending = False
        self._forget_motion()

    @micropython.native
    def _set_rpm(self, q, off):
        rpm = f32_to_q(q, off, RPM_Q)
        self.qd_set = rpm
        if rpm == 0 or self._motion_allowed:  # _may_move(), inlined: a host streams SETRPM
            self.hal.set_rpm(rpm)
            self.positioning = False
            self.target_known = False

    def _move_steps(self, q, off):
        if self._may_move():
            self.hal.move_steps(i32(q, off))
            self._positioning_started()

    def _move_angle(self, q, off):
        if self._may_move():
            self.hal.move_angle(f32_to_q(q, off, ANGLE_Q))
            self._positioning_started()

    def _move_to_angle(self, q, off):
        self.q_set = f32_to_q(q, off, ANGLE_Q)
        if self._may_move():
            self.hal.move_to_angle(self.q_set - self.zero_offset)
            self._positioning_started()
            self.target_known = True  # q_set is where this move ends (the deadman's hold window)

    def _positioning_started(self):
        self.positioning = True
        self.target_known = False
        self.qd_set = 0

    def _set_current(self, q, off):
        self.drive_current = q[off]
        self.hal.set_current(self.drive_current)

    def _set_hold_current(self, q, off):
        self.hold_current = q[off]
        self.hal.set_hold_current(self.hold_current)

    def _set_max_acceleration(self, q, off):
        value = _full_steps(q, off)
        self.max_acceleration = self.max_deceleration = value
        self.hal.set_max_acceleration(value)
        self.hal.set_max_deceleration(value)

    def _set_max_deceleration(self, q, off):
        self.max_deceleration = _full_steps(q, off)
        self.hal.set_max_deceleration(self.max_deceleration)

    def _set_max_velocity(self, q, off):
        self.hal.set_max_velocity(_full_steps(q, off))

    def _enable_stallguard(self, q, off):
        self.stall.sensitivity = q[off]
        self.stall.reset()
        self._forget_motion()
        self.stallguard = True
        # The detectors' deadlines stood still while they were off: both due now.
        self._next_stall_ms = self._next_track_ms = self._next_sample_ms = self.clock.ticks_ms()

    def _disable_stallguard(self, q, off):
        self.stallguard = False

    def _clear_stall(self, q, off):
        self.stall.reset()
        self._forget_motion()

    def _set_brake_mode(self, q, off):
        self.hal.set_brake_mode(q[off])

    def _enable_closed_loop(self, q, off):
        self.hal.enable_closed_loop()
        self.closed_loop = True

    def _disable_closed_loop(self, q, off):
        self.hal.disable_closed_loop()
        self.closed_loop = False

    def _check_orientation(self, q, off):
        # The sign would only swap what counts as inverted: a negative angle would flip a
        # correctly wired motor into closed-loop runaway.
        self._start_task("CHECKORIENTATION", self._orientation(abs(f32_to_q(q, off, ANGLE_Q))),
                         q[off + _EPOCH])

    def _set_watchdog(self, q, off):
        self.watchdog_ms = q[off] | (q[off + 1] << 8)
        struct.pack_into("<H", self._cache[WATCHDOG], 0, self.watchdog_ms)

    def _home(self, q, off):
        self._start_task("HOME", self._homing(q[off], q[off + 1], q[off + 2], q[off + 3]), q[off + _EPOCH])
