"""The joint core's main-loop context: apply queued commands, step tasks, refresh reply caches.

`service()` runs once per main-loop iteration: it drains the IRQ's command queue in arrival order
into the motor HAL (`handlers.py`), steps the running blocking task (`tasks.py`), runs the
supervision (`supervise.py`) and packs the reply caches the IRQ serves. Its writes to state the IRQ
reads are wrapped in `critical` sections, except the float caches: one 32-bit store each (store_q).
"""

from ..micro import const, micropython

from ..motion.fixed import store_q
from .irq import FTAB_DISABLED, FTAB_HALTS, FTAB_REARMS, FTAB_TASK
from ..spec.protocol import FLAG_BUSY, FLAG_NOTENABLED


# What service() and _apply_next() use, as constants of this module: another module's name is a
# global lookup on every use (~1.5 us on the chip). test_irq_path checks them against their sources.
_ANGLE_Q = const(12)
_RPM_Q = const(16)
_ANGLEMOVED = const(0x18)
_GETENCODERRPM = const(0x2C)
_GETDRIVERRPM = const(0x12)
_GETPIDERROR = const(0x2A)
_LASTERROR = const(0x31)
_SLOT_MASK = const(15)  # QUEUE_SLOTS - 1
_SLOT = const(8)
_SLOT_FLAGS = const(5)
_SLOT_HALTS = const(6)
_SLOT_STOPS = const(7)
_MOTION_BLOCKED = const(9)
_FTAB_BLOCK_OUT = const(1540)
_FTAB_REJECTS = const(1550)
_FTAB_Q_IN = const(1553)
_FTAB_Q_OUT = const(1554)


class MainLoop:
    """JointController's main-loop methods (mixed into it)."""

    def cached_reply(self, addr):
        """The reply payload bytes the IRQ path serves for register `addr` (None: not readable)."""
        return self._cache[addr] if 0 <= addr < len(self._cache) else None

    @micropython.native
    def service(self):
        """One main-loop iteration; call it every millisecond or faster. One method: on the chip
        a call costs 10-17 us and an attribute load ~6, so the every-iteration work is inlined
        here and the rest is called only when it has something to do."""
        # The commands queued before this iteration: one the IRQ queues while it runs (the
        # host's traffic landing in it) waits for the next, so its cost and theirs do not add up.
        ftab = self._ftab
        q_in = ftab[_FTAB_Q_IN]
        clock = self.clock
        now = clock.ticks_ms()
        if not self.disabled:
            try:
                hal = self.hal
                hal.update()
                if self.stops != self._stops_seen:
                    self._stops_seen = self.stops
                    hal.set_rpm(0)
                    self.qd_set = 0
                    self.positioning = False
                applied = 0
                while ftab[_FTAB_Q_OUT] != q_in:
                    self._apply_next()
                    applied = 1
                if self._task is not None and (clock.ticks_diff(now, self._task_wake) >= 0
                                               or self._cancelled()):
                    self._step_task(now)
                if self.positioning and hal.position_reached():
                    self.positioning = False
                # The detectors (when on) wait one iteration, never more, after one that
                # applied a command: the two heaviest jobs do not share an iteration.
                if self.stallguard and clock.ticks_diff(now, self._next_sample_ms) >= applied:
                    self._sample_detectors(now)
                # The deadman: every mode (WATCHDOG) or its quick stop in _check_deadman; the
                # original's (velocity only) called once the host has been silent long enough.
                if self.watchdog_ms or self._safe_pending:
                    self._check_deadman()
                elif self.qd_set and clock.ticks_diff(clock.ticks_us(), self.host_us) >= self._deadman_us:
                    self._check_deadman()
                # The reply caches, each packed only when its value changed. Work split by rate:
                # the angle every iteration, the encoder speed every second one, the driver speed
                # and the PID error every fourth (at most 2 and 4 ms old).
                last = self.reply_values
                value = hal.angle_moved() + self.zero_offset  # _host_angle(), inlined
                if value != last[0]:
                    last[0] = value
                    store_q(self._cache[_ANGLEMOVED], value, _ANGLE_Q)
                turn = (self._cache_turn + 1) & 3
                self._cache_turn = turn
                if turn & 1 == 0:
                    value = hal.encoder_rpm()
                    addr = _GETENCODERRPM
                    q = _RPM_Q
                    turn = 1
                elif turn == 1:
                    value = hal.driver_rpm()
                    addr = _GETDRIVERRPM
                    q = _RPM_Q
                    turn = 2
                else:
                    value = hal.pid_error()
                    addr = _GETPIDERROR
                    q = 0
                if value != last[turn]:
                    last[turn] = value
                    store_q(self._cache[addr], value, q)
            except Exception as exc:
                self._motor_fault(exc)
        if self._ftab[_FTAB_REJECTS] != self._logged_rejects:  # (one byte: wraps at 256, not between two passes)
            self._logged_rejects = self._ftab[_FTAB_REJECTS]
            cache = self._cache[_LASTERROR]
            # The reason by number: the board keeps no reason texts (heap); `bioscara console` says the words.
            self.log.warn("rejected a frame for register 0x%02x: reason %d" % (cache[1], cache[0]))

    def _motor_fault(self, exc):
        """The motor backend failed (driver or encoder unreachable): disable the joint for good."""
        self.disabled = True
        self._ftab[FTAB_DISABLED] = 1  # what the IRQ's judge reads
        self._task = None
        self._ftab[FTAB_TASK] = 0
        self.task_name = None
        state = self._irq_off()
        self.flags = (self.flags | FLAG_NOTENABLED) & ~FLAG_BUSY
        self._irq_on(state)
        self.ready = True
        self.log.error("motor fault, joint disabled until reset: %r" % (exc,))

    def _sample_detectors(self, now):
        """The stall detectors at their own periods; the loop checks only the earlier deadline.
        The next deadline follows the last one, not the sample: one deferred an iteration (after
        an apply) must not stretch the period the detectors' filters assume."""
        clock = self.clock
        if clock.ticks_diff(now, self._next_stall_ms) >= 0:
            self._next_stall_ms = _next_deadline(clock, self._next_stall_ms, now, self._stall_period_ms)
            self._check_stall()
        if clock.ticks_diff(now, self._next_track_ms) >= 0:
            self._next_track_ms = _next_deadline(clock, self._next_track_ms, now, self.track.sample_ms)
            self._check_tracking()
        stall, track = self._next_stall_ms, self._next_track_ms
        self._next_sample_ms = stall if clock.ticks_diff(stall, track) <= 0 else track

    def _set_flags(self, mask):
        state = self._irq_off()
        self.flags |= mask
        self._irq_on(state)

    def _clear_flags(self, mask):
        state = self._irq_off()
        self.flags &= ~mask
        self._irq_on(state)

    @micropython.native
    def _apply_next(self):
        ftab = self._ftab
        q_out = ftab[_FTAB_Q_OUT]
        base = (q_out & _SLOT_MASK) * _SLOT
        queue = self._queue
        addr = queue[base]
        # Motion is judged by the state in command order: the flags right after this command was
        # accepted, and nothing stopped the motor (STOP, stall, deadman) since then.
        self._motion_allowed = (not queue[base + _SLOT_FLAGS] & _MOTION_BLOCKED
                                and queue[base + _SLOT_HALTS] == self.halts)
        if self.registers.blocking[addr]:
            if queue[base + _SLOT_STOPS] == self.stops:
                self._finish_cancelled_task()
                self._handlers[addr](queue, base + 1)
            else:
                self.log.info("%s cancelled by STOP before it started" % self.registers.name(addr))
            ftab[_FTAB_BLOCK_OUT] = (ftab[_FTAB_BLOCK_OUT] + 1) & 0xFF
        else:
            self._handlers[addr](queue, base + 1)
        ftab[_FTAB_Q_OUT] = (q_out + 1) & 0xFF

    def _may_move(self):
        return self._motion_allowed

    def _halt(self, flag, rearms=-1, transactions=-1):
        """Set `flag` and invalidate queued motion, unless the host re-armed the joint (a frame
        cleared STALL: `rearms` changed) or spoke (`transactions` changed) since the decision.
        Returns whether it halted."""
        state = self._irq_off()
        if (rearms >= 0 and rearms != self._ftab[FTAB_REARMS]
                or transactions >= 0 and transactions != self.transactions):
            self._irq_on(state)
            return False
        self.flags |= flag
        self.halts = (self.halts + 1) & 0xFF
        self._ftab[FTAB_HALTS] = self.halts  # what the IRQ's judge reads
        self._irq_on(state)
        self.qd_set = 0
        self.positioning = False
        return True


def _next_deadline(clock, deadline, now, period_ms):
    """`period_ms` after `deadline`; from `now` if that is already past (a stall of the loop, or
    detection just turned on): no burst of samples to catch up."""
    following = clock.ticks_add(deadline, period_ms)
    if clock.ticks_diff(following, now) <= 0:
        return clock.ticks_add(now, period_ms)
    return following
