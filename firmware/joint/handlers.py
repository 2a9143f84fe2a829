"""The joint core's register handlers: one per command register, run by the main loop.

Each gets the queue and the payload offset of its slot (`loop.py` drains the queue in order).
"""

import struct

_DEG_TO_FULL_STEPS = 200.0 / 360.0


def _f32(buf, off):
    return struct.unpack_from("<f", buf, off)[0]


class Handlers:
    """JointController's register handlers (mixed into it): (queue, payload offset), main loop."""

    def _setup(self, q, off):
        self.drive_current = q[off]
        self.hold_current = q[off + 1]
        self.hal.set_current(self.drive_current)
        self.hal.set_hold_current(self.hold_current)
        self.hal.move_steps(0)
        self.stallguard = False
        self.qd_set = 0.0
        self.positioning = False

    def _set_rpm(self, q, off):
        rpm = _f32(q, off)
        self.qd_set = rpm
        if rpm == 0 or self._may_move():
            self.hal.set_rpm(rpm)
            self.positioning = False

    def _move_steps(self, q, off):
        if self._may_move():
            self.hal.move_steps(struct.unpack_from("<i", q, off)[0])
            self._positioning_started()

    def _move_angle(self, q, off):
        if self._may_move():
            self.hal.move_angle(_f32(q, off))
            self._positioning_started()

    def _move_to_angle(self, q, off):
        self.q_set = _f32(q, off)
        if self._may_move():
            self.hal.move_to_angle(self.q_set)
            self._positioning_started()

    def _positioning_started(self):
        self.positioning = True
        self.qd_set = 0.0

    def _set_current(self, q, off):
        self.drive_current = q[off]
        self.hal.set_current(self.drive_current)

    def _set_hold_current(self, q, off):
        self.hold_current = q[off]
        self.hal.set_hold_current(self.hold_current)

    def _set_max_acceleration(self, q, off):
        value = abs(_f32(q, off)) * _DEG_TO_FULL_STEPS
        self.hal.set_max_acceleration(value)
        self.hal.set_max_deceleration(value)

    def _set_max_deceleration(self, q, off):
        self.hal.set_max_deceleration(abs(_f32(q, off)) * _DEG_TO_FULL_STEPS)

    def _set_max_velocity(self, q, off):
        self.hal.set_max_velocity(abs(_f32(q, off)) * _DEG_TO_FULL_STEPS)

    def _enable_stallguard(self, q, off):
        self.stall.sensitivity = q[off]
        self.stall.reset()
        self.stallguard = True

    def _disable_stallguard(self, q, off):
        self.stallguard = False

    def _clear_stall(self, q, off):
        self.stall.reset()

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
        self._start_task("CHECKORIENTATION", self._orientation(abs(_f32(q, off))))

    def _home(self, q, off):
        self._start_task("HOME", self._homing(q[off], q[off + 1], q[off + 2], q[off + 3]))
