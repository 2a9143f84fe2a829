"""The joint core's blocking commands: HOME and CHECKORIENTATION as generator tasks (the boot task
is core_init.py's).

A task holds BUSY while it runs; the main loop steps it when its wait is over (each `yield` says
how many milliseconds to wait) or a STOP cancelled it.
"""

import struct

from ..motion.fixed import ANGLE_Q, RPM_Q, muldiv, store_q
from ..detect.homing import HOMED, RUNNING
from .irq import FTAB_TASK, FTAB_TASK_STOPS
from ..spec.protocol import ENCODERZERO, FLAG_BUSY, FLAG_NOTHOMED, FLAG_STALL, HOMINGRESULT, HOMINGTRAVEL
from ..detect.tracking import wrapped_diff
from ..micro import const

_HOMING_SETTLE_MS = const(500)
_REST_MS = const(100)
_REST_USTEPS = const(24)  # a few encoder counts of noise
_SETTLE_MAX_MS = const(3000)
_MOVE_TIMEOUT_MS = const(10000)
_ORIENTATION_MAX_ROUNDS = const(10)
_WIND_DOWN_STEPS = const(8)


def _usteps_to_angle(usteps):
    """usteps as motor degrees Q12 (x 360 * 4096 / 51200 = 144 / 5)."""
    if usteps >= 0:
        return muldiv(usteps, 144, 5)
    return -muldiv(-usteps, 144, 5)


class Tasks:
    """JointController's blocking commands (mixed into it): generators yielding milliseconds to wait."""

    def _start_task(self, name, task, stops):
        """Run `task` for the command accepted in stop epoch `stops` (its queue slot's: a STOP
        that came after the command cancels the task, even one that came while it was applied)."""
        ftab = self._ftab
        ftab[FTAB_TASK_STOPS] = stops  # before FTAB_TASK: the IRQ reads both
        ftab[FTAB_TASK] = 1
        self.task_name = name
        self._task_wake = self.clock.ticks_ms()
        self._task = task

    def _cancelled(self):
        return self._ftab[FTAB_TASK_STOPS] != self.stops

    def _step_task(self, now):
        try:
            wait = next(self._task)
            self._task_wake = self.clock.ticks_add(now, wait)
        except StopIteration:
            self._end_task()

    def _end_task(self):
        # One critical section: a blocking command accepted in between would otherwise lose its
        # BUSY. A cancelled task's BUSY went with the STOP and may belong to a newer command now.
        state = self._irq_off()
        if not self._cancelled():
            self.flags &= ~FLAG_BUSY
        self._task = None
        self._ftab[FTAB_TASK] = 0
        self._irq_on(state)
        self.task_name = None

    def _finish_cancelled_task(self):
        """Let a task a STOP cancelled wind down (it does not wait any more) before a new one."""
        task = self._task
        if task is None:
            return
        for _ in range(_WIND_DOWN_STEPS):
            try:
                next(task)
            except StopIteration:
                break
        else:
            task.close()
        self._end_task()

    def _wait_reached(self):
        """Wait for a positioning move; False on timeout or when a STOP cancelled the task."""
        waited = 0
        while not self.hal.position_reached():
            if waited >= _MOVE_TIMEOUT_MS or self._cancelled():
                return False
            waited += 1
            yield 1
        return True

    def _orientation(self, degrees):
        """The stepper library's checkOrientation: +/- moves of `degrees` (Q12) until two agree.


        Unlike the library it gives up on a STOP or a move that never arrives (the library
        waited forever), keeping the driver direction it had.
        """
        hal = self.hal
        hal.disable_closed_loop()
        hal.set_inverted(False)
        inverted = normal = rounds = 0
        while inverted < 2 and normal < 2:
            rounds += 1
            if rounds > _ORIENTATION_MAX_ROUNDS:
                self.log.error("orientation check inconclusive after %d rounds" % (rounds - 1))
                break
            start = hal.angle_moved()
            hal.move_angle(degrees)
            if not (yield from self._wait_reached()):
                break
            if hal.angle_moved() < start:
                inverted += 1
            else:
                normal += 1
            hal.move_angle(-degrees)
            if not (yield from self._wait_reached()):
                break
            if inverted and normal:
                inverted = normal = 0
        if inverted >= 2 or normal >= 2:
            self.inverted = inverted >= 2
            if self.inverted:
                self.log.info("motor wiring inverted: driver direction reversed")
        else:
            hal.stop(True)
            self.log.error("orientation check %s; driver direction unchanged"
                           % ("stopped" if self._cancelled() else "did not finish"))
        hal.set_inverted(self.inverted)
        if self.closed_loop:
            hal.enable_closed_loop()

    def _homing(self, direction, speed, sensitivity, current):
        """Drive into the end stop until homing.py sees it (the encoder stops following the field,
        sustained); a travel limit or timeout ends it NOTHOMED, STOP (BUSY cleared) aborts it.
        The motor holds at the homing current throughout: a back-drivable load must not fall."""
        hal = self.hal
        monitor = self.homing
        self.qd_set = 0
        self.positioning = False
        hal.set_current(current)
        hal.set_hold_current(current)
        hal.stop(True)
        struct.pack_into("<B", self._cache[HOMINGRESULT], 0, RUNNING)  # a reply cache, as handlers.py writes them
        clock = self.clock
        # The encoder's own word on its magnet first (the AS5600's status), then the settle.
        outcome = monitor.check_magnet(hal.magnet())
        if outcome == RUNNING:
            outcome = yield from self._rest_check()
        if outcome == RUNNING and not self._cancelled():
            hal.set_rpm((speed if direction else -speed) << RPM_Q)
            monitor.start(1 if direction else -1, speed, sensitivity, hal.field_position(),
                          self._encoder_usteps())
            every = monitor.sample_ms
            start = clock.ticks_ms()
            due = clock.ticks_add(start, every)
            while not self._cancelled():
                monitor.watch(hal.pid_error(), self._encoder_usteps())
                now = clock.ticks_ms()
                if clock.ticks_diff(now, due) >= 0:  # by the clock: the loop may run slower than 1 kHz
                    due = clock.ticks_add(now, every)
                    outcome = monitor.sample(hal.field_position(), self._encoder_usteps(),
                                             clock.ticks_diff(now, start))
                    if outcome != RUNNING:
                        break
                yield 1
        hal.stop(True)
        if outcome == HOMED:
            yield from self._settle()
        if outcome == HOMED and not self._cancelled():
            # The rotor rebounds off the stop (far, on a stiff stop behind backlash): the zero is
            # the deepest point the encoder reached while pushing, not where the rotor came to rest.
            rest = self._encoder_usteps()
            travel = _usteps_to_angle(wrapped_diff(monitor.deepest, monitor.start_encoder))
            store_q(self._cache[HOMINGTRAVEL], travel, ANGLE_Q)
            hal.set_home()
            self.zero_offset = _usteps_to_angle(wrapped_diff(rest, monitor.deepest))
            # ENCODERZERO: the sensor's own angle where the host's angle is 0 (boot: where begin() zeroed it).
            store_q(self._cache[ENCODERZERO], (hal.encoder_zero() - self.zero_offset) % (360 << ANGLE_Q), ANGLE_Q)
            self._clear_flags(FLAG_NOTHOMED | FLAG_STALL)
            self.log.info("homed")
        else:
            self._set_flags(FLAG_NOTHOMED)
            # By number: the board keeps no outcome texts (heap); `bioscara console` says the words.
            if outcome == RUNNING:
                self.log.warn("homing ended, not homed: aborted by STOP")
            else:
                self.log.warn("homing ended, not homed: outcome %d" % outcome)
        struct.pack_into("<B", self._cache[HOMINGRESULT], 0, outcome)
        hal.set_current(self.drive_current)
        hal.set_hold_current(self.hold_current)
        self._forget_motion()

    def _rest_check(self):
        """The homing's settle, doubling as a check in its second half (the first lets a link that
        fell while the coils were off be caught): the encoder's jumps while the motor holds. The
        outcome so far: RUNNING, NOISY or MOVING."""
        clock = self.clock
        monitor = self.homing
        yield _HOMING_SETTLE_MS // 2
        start = clock.ticks_ms()
        monitor.rest(self._encoder_usteps(), True)
        while clock.ticks_diff(clock.ticks_ms(), start) < _HOMING_SETTLE_MS // 2 and not self._cancelled():
            yield 1
            monitor.rest(self._encoder_usteps(), False)
        if not self._cancelled() and monitor.noisy():
            return monitor.outcome
        return RUNNING

    def _settle(self):
        """Wait (at most _SETTLE_MAX_MS) until the encoder has moved less than _REST_USTEPS in
        _REST_MS: the rotor has come to rest after the stop."""
        clock = self.clock
        start = clock.ticks_ms()
        mark = clock.ticks_ms()
        last = self._encoder_usteps()
        while not self._cancelled():
            yield 1
            now = clock.ticks_ms()
            here = self._encoder_usteps()
            moved = here - last
            if moved > _REST_USTEPS or -moved > _REST_USTEPS:
                last = here
                mark = now
            elif clock.ticks_diff(now, mark) >= _REST_MS:
                return
            if clock.ticks_diff(now, start) >= _SETTLE_MAX_MS:
                return
