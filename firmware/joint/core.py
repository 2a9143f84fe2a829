"""Joint controller core: register semantics, flags, blocking commands, stall detection, deadman.

Two contexts touch this object:

* the I2C IRQ path (`on_frame`, `reply_into`, `host_seen`), which must never allocate: it
  validates a frame with the protocol's byte-level checks, applies the command's flag changes as
  integer updates (so the reply already shows the command's effect, as the original firmware's
  did), copies the command into a preallocated queue slot and answers from reply bytes the main
  loop packed in advance;
* the main loop (`service`), which drains the queue in arrival order into the motor HAL, runs the
  blocking commands (boot, HOME, CHECKORIENTATION) as generator tasks holding BUSY, samples stall
  detection every `stall.sample_time`, watches the deadman and refreshes the reply caches. Its
  writes to state the IRQ reads are wrapped in `critical` sections.

No hardware module is imported here: the HAL, clock, logger and IRQ masking are injected.
"""

import struct

from .protocol import (
    ANGLEMOVED, BY_ADDR, CHECKORIENTATION, CLEARSTALL, DISABLECLOSEDLOOP, DISABLESTALLGUARD,
    ENABLECLOSEDLOOP, ENABLESTALLGUARD, FLAG_BUSY, FLAG_ERROR, FLAG_NOTENABLED, FLAG_NOTHOMED,
    FLAG_STALL, FLAGS_AT_BOOT, GETDRIVERRPM, GETENCODERRPM, GETPIDERROR, HOME, HOMEOFFSET, IDENTITY,
    LASTERROR, MAX_FRAME, MOVEANGLE, MOVESTEPS, MOVETOANGLE, PING, PROTOCOL, PROTOCOL_VERSION,
    REJECT_BUSY,
    REJECT_DISABLED, REJECT_NONE, REJECT_QUEUE_FULL, REJECT_UNKNOWN_REGISTER, SETBRAKEMODE,
    SETCURRENT, SETHOLDCURRENT, SETMAXACCELERATION, SETMAXDECELERATION, SETMAXVELOCITY, SETRPM,
    SETUP, SPEC_HASH, STOP, ACK, reject_string,
)
from .stall import StallDetector
from .version import FIRMWARE_VERSION

try:
    from micropython import const
except ImportError:
    def const(value):
        return value

_QUEUE_SLOTS = const(16)  # a power of two, so slot = counter % slots survives counter wrap
# A slot: the frame, then what held when it was accepted: the flags right after it, the halt epoch
# and the stop epoch (8 bits each; a slot lives for about a millisecond).
_SLOT = MAX_FRAME + 3
_SLOT_FLAGS = MAX_FRAME
_SLOT_HALTS = MAX_FRAME + 1
_SLOT_STOPS = MAX_FRAME + 2
_MOTION_BLOCKED = FLAG_STALL | FLAG_NOTENABLED
# IRQ counters wrap here: +1 must stay a small int on 32-bit ports (largest 2**30 - 1) even before
# the mask, or the hard IRQ would allocate a long int.
COUNTER_MASK = const(0x1FFFFFFF)
_DEG_TO_FULL_STEPS = 200.0 / 360.0
_HOMING_SETTLE_MS = const(500)
_MOVE_TIMEOUT_MS = const(10000)
_ORIENTATION_MAX_ROUNDS = const(10)
_WIND_DOWN_STEPS = const(8)


def _no_irq_off():
    return 0


def _no_irq_on(state):
    pass


def _f32(buf, off):
    return struct.unpack_from("<f", buf, off)[0]


class JointController:
    """The firmware of one joint, independent of the I2C peripheral and the motor backend."""

    def __init__(self, hal, clock, cfg, log, critical=None):
        self.hal = hal
        self.clock = clock
        self.cfg = cfg
        self.log = log
        self._irq_off, self._irq_on = critical or (_no_irq_off, _no_irq_on)
        self.flags = FLAGS_AT_BOOT | FLAG_BUSY
        self.ready = False
        self.disabled = not cfg.valid
        # Setpoints and modes (main loop).
        self.drive_current = 0
        self.hold_current = 0
        self.qd_set = 0.0
        self.q_set = 0.0
        self.positioning = False
        self.closed_loop = False
        self.inverted = False
        self.stallguard = False
        self.stall = StallDetector(cfg.stall)
        self.trace = None  # main loop: called with the detector after every stall-detection sample
        # Reply caches: bytes of every readable register, packed ahead of the read.
        self._cache = [None] * 256
        for addr in range(256):
            reg = BY_ADDR[addr]
            if reg is not None and reg.readable:
                self._cache[addr] = bytearray(reg.rsize)
        self._cache[PING][0] = ACK
        struct.pack_into("<BBBBBI", self._cache[IDENTITY], 0, PROTOCOL_VERSION, FIRMWARE_VERSION[0],
                         FIRMWARE_VERSION[1], FIRMWARE_VERSION[2], cfg.joint_id, SPEC_HASH)
        # IRQ-side state: the reply the next read gets, the command queue, counters.
        self._reply_reg = BY_ADDR[PING]
        self._reply_err = 0
        self._queue = bytearray(_QUEUE_SLOTS * _SLOT)
        self._q_in = 0  # written by the IRQ path only
        self._q_out = 0  # written by the main loop only
        self._blocking_in = 0  # blocking commands accepted (IRQ) ...
        self._blocking_out = 0  # ... and taken from the queue (main loop)
        self._blocking_stops = 0  # stop epoch when the latest blocking command was accepted
        self.transactions = 0
        # Epochs (8 bits). `stops`: STOP frames (IRQ); a task or queued blocking command from an
        # older epoch is cancelled. `halts`: whatever stopped the motor (STOP in the IRQ, stall or
        # deadman in the main loop); queued motion from an older epoch is not applied.
        # `stall_rearms`: frames that cleared STALL, so a stall decided before one is dropped.
        self.stops = 0
        self.halts = 0
        self.stall_rearms = 0
        self._stops_seen = 0
        self._motion_allowed = False
        self.rejects = 0
        self._logged_rejects = 0
        # Main-loop bookkeeping.
        now = clock.ticks_ms()
        self._seen_transactions = 0
        self._last_host_ms = now
        self._next_stall_ms = now
        self._stall_period_ms = int(cfg.stall.sample_time * 1000 + 0.5)
        self._task = None
        self.task_name = None
        self._task_stops = 0  # the stop epoch the running task belongs to
        self._task_wake = now
        self._handlers = {
            SETUP: self._setup, SETRPM: self._set_rpm, MOVESTEPS: self._move_steps,
            MOVEANGLE: self._move_angle, MOVETOANGLE: self._move_to_angle,
            SETCURRENT: self._set_current, SETHOLDCURRENT: self._set_hold_current,
            SETMAXACCELERATION: self._set_max_acceleration,
            SETMAXDECELERATION: self._set_max_deceleration, SETMAXVELOCITY: self._set_max_velocity,
            ENABLESTALLGUARD: self._enable_stallguard, DISABLESTALLGUARD: self._disable_stallguard,
            CLEARSTALL: self._clear_stall, SETBRAKEMODE: self._set_brake_mode,
            ENABLECLOSEDLOOP: self._enable_closed_loop, DISABLECLOSEDLOOP: self._disable_closed_loop,
            CHECKORIENTATION: self._check_orientation, HOME: self._home,
            PROTOCOL: self._select_protocol,
        }
        self.protocol_request = 0  # a PROTOCOL write (main loop); the protocol switch acts on it
        if self.disabled:
            for problem in cfg.errors:
                log.error(problem)
            log.error("invalid configuration: joint disabled, commands are rejected")
            self.flags = FLAGS_AT_BOOT
            self.ready = True
        else:
            self._start_task("boot", self._boot())

    # ---- IRQ path: no allocation below this line until the main-loop section ----

    def host_seen(self):
        """A transaction addressed to this joint ended (feeds the deadman)."""
        self.transactions = (self.transactions + 1) & COUNTER_MASK

    def on_frame(self, frame, n):
        """A write of n bytes (register + payload) ended. `frame` holds at most MAX_FRAME bytes."""
        if n == 0:
            return  # address probe (bus scan)
        addr = frame[0]
        reg = BY_ADDR[addr]
        if reg is None:
            self._reject(addr, REJECT_UNKNOWN_REGISTER)
            return
        if n == 1 and reg.readable:
            self._reply_reg = reg
            self._reply_err = 0
            return
        reason = reg.check_write(frame, 1, n - 1)
        if reason == REJECT_NONE:
            if self.disabled:
                reason = REJECT_DISABLED
            elif reg.blocking and self._blocking_live():
                reason = REJECT_BUSY
            elif (addr != HOMEOFFSET and addr != STOP
                  and ((self._q_in - self._q_out) & COUNTER_MASK) >= _QUEUE_SLOTS):
                reason = REJECT_QUEUE_FULL
        if reason != REJECT_NONE:
            self._reject(addr, reason)
            return
        flags = (self.flags | reg.sets) & ~reg.clears
        if reg.zero_sets and frame[1] == 0:
            flags |= reg.zero_sets
        self.flags = flags
        if reg.clears & FLAG_STALL:
            self.stall_rearms = (self.stall_rearms + 1) & 0xFF
        if addr == STOP:
            # Immediate, as in the original's ISR: cancels the running blocking command and any
            # motion still queued; the main loop commands 0 RPM next.
            self.stops = (self.stops + 1) & 0xFF
            self.halts = (self.halts + 1) & 0xFF
        elif addr == HOMEOFFSET:
            cache = self._cache[HOMEOFFSET]
            for i in range(4):
                cache[i] = frame[1 + i]
        else:
            base = (self._q_in % _QUEUE_SLOTS) * _SLOT
            queue = self._queue
            for i in range(n):
                queue[base + i] = frame[i]
            queue[base + _SLOT_FLAGS] = flags
            queue[base + _SLOT_HALTS] = self.halts
            queue[base + _SLOT_STOPS] = self.stops
            if reg.blocking:
                self._blocking_stops = self.stops
                self._blocking_in = (self._blocking_in + 1) & COUNTER_MASK
            self._q_in = (self._q_in + 1) & COUNTER_MASK
        self._reply_reg = None
        self._reply_err = 0

    def _blocking_live(self):
        """A blocking command is queued or running and no STOP has cancelled it."""
        if self._blocking_in != self._blocking_out and self._blocking_stops == self.stops:
            return True
        return self._task is not None and self._task_stops == self.stops

    def _reject(self, addr, reason):
        self._reply_reg = None
        self._reply_err = FLAG_ERROR
        self.rejects = (self.rejects + 1) & 0xFFFF
        cache = self._cache[LASTERROR]
        cache[0] = reason
        cache[1] = addr
        cache[2] = self.rejects & 0xFF
        cache[3] = self.rejects >> 8

    def reply_into(self, out):
        """Write the reply (payload + flags) right-aligned at the end of `out`; return its length."""
        end = len(out)
        out[end - 1] = self.flags | self._reply_err
        reg = self._reply_reg
        if reg is None:
            return 1
        n = reg.rsize
        cache = self._cache[reg.addr]
        start = end - 1 - n
        for i in range(n):
            out[start + i] = cache[i]
        return n + 1

    # ---- main loop ----

    def cached_reply(self, addr):
        """The reply payload bytes the IRQ path serves for register `addr` (None: not readable)."""
        return self._cache[addr]

    def service(self):
        """One main-loop iteration; call it every millisecond or faster."""
        now = self.clock.ticks_ms()
        if self.transactions != self._seen_transactions:
            self._seen_transactions = self.transactions
            self._last_host_ms = now
        if not self.disabled:
            try:
                self._service_motor(now)
            except Exception as exc:
                self._motor_fault(exc)
        if self.rejects != self._logged_rejects:
            self._logged_rejects = self.rejects
            cache = self._cache[LASTERROR]
            self.log.warn("rejected a frame for register 0x%02x: %s" % (cache[1], reject_string(cache[0])))

    def _motor_fault(self, exc):
        """The motor backend failed (driver or encoder unreachable): disable the joint for good."""
        self.disabled = True
        self._task = None
        self.task_name = None
        state = self._irq_off()
        self.flags = (self.flags | FLAG_NOTENABLED) & ~FLAG_BUSY
        self._irq_on(state)
        self.ready = True
        self.log.error("motor fault, joint disabled until reset: %r" % (exc,))

    def _service_motor(self, now):
        diff = self.clock.ticks_diff
        self.hal.update()
        if self.stops != self._stops_seen:
            self._stops_seen = self.stops
            self.hal.set_rpm(0)
            self.qd_set = 0.0
            self.positioning = False
        while self._q_out != self._q_in:
            self._apply_next()
        if self._task is not None and (diff(now, self._task_wake) >= 0 or self._cancelled()):
            self._step_task(now)
        if self.positioning and self.hal.position_reached():
            self.positioning = False
        if diff(now, self._next_stall_ms) >= 0:
            self._next_stall_ms = self.clock.ticks_add(now, self._stall_period_ms)
            self._check_stall()
        self._check_deadman(now)
        self._refresh_caches()

    def _set_flags(self, mask):
        state = self._irq_off()
        self.flags |= mask
        self._irq_on(state)

    def _clear_flags(self, mask):
        state = self._irq_off()
        self.flags &= ~mask
        self._irq_on(state)

    def _refresh_caches(self):
        hal = self.hal
        angle, rpm, driver, error = hal.angle_moved(), hal.encoder_rpm(), hal.driver_rpm(), hal.pid_error()
        cache = self._cache
        state = self._irq_off()
        struct.pack_into("<f", cache[ANGLEMOVED], 0, angle)
        struct.pack_into("<f", cache[GETENCODERRPM], 0, rpm)
        struct.pack_into("<f", cache[GETDRIVERRPM], 0, driver)
        struct.pack_into("<f", cache[GETPIDERROR], 0, error)
        self._irq_on(state)

    def _apply_next(self):
        base = (self._q_out % _QUEUE_SLOTS) * _SLOT
        queue = self._queue
        addr = queue[base]
        # Motion is judged by the state in command order: the flags right after this command was
        # accepted, and nothing stopped the motor (STOP, stall, deadman) since then.
        self._motion_allowed = (not queue[base + _SLOT_FLAGS] & _MOTION_BLOCKED
                                and queue[base + _SLOT_HALTS] == self.halts)
        if BY_ADDR[addr].blocking:
            if queue[base + _SLOT_STOPS] == self.stops:
                self._finish_cancelled_task()
                self._handlers[addr](queue, base + 1)
            else:
                self.log.info("%s cancelled by STOP before it started" % BY_ADDR[addr].name)
            self._blocking_out = (self._blocking_out + 1) & COUNTER_MASK
        else:
            self._handlers[addr](queue, base + 1)
        self._q_out = (self._q_out + 1) & COUNTER_MASK

    def _may_move(self):
        return self._motion_allowed

    def _halt(self, flag, rearms=-1, transactions=-1):
        """Set `flag` and invalidate queued motion, unless the host re-armed the joint (a frame
        cleared STALL: `rearms` changed) or spoke (`transactions` changed) since the decision.
        Returns whether it halted."""
        state = self._irq_off()
        if (rearms >= 0 and rearms != self.stall_rearms
                or transactions >= 0 and transactions != self.transactions):
            self._irq_on(state)
            return False
        self.flags |= flag
        self.halts = (self.halts + 1) & 0xFF
        self._irq_on(state)
        self.qd_set = 0.0
        self.positioning = False
        return True

    # Register handlers: (queue, payload offset), main loop.

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

    def _select_protocol(self, q, off):
        self.protocol_request = q[off]

    # Blocking commands: generators yielding how many milliseconds to wait.

    def _start_task(self, name, task):
        self._task_stops = self.stops  # before _task: the IRQ reads both
        self.task_name = name
        self._task_wake = self.clock.ticks_ms()
        self._task = task

    def _cancelled(self):
        return self._task_stops != self.stops

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

    def _boot(self):
        """The original setup(): closed loop, boot limits, orientation check, then freewheel."""
        hal = self.hal
        boot = self.cfg.boot
        hal.begin()
        hal.enable_closed_loop()
        self.closed_loop = True
        hal.set_max_acceleration(boot.max_acceleration)
        hal.set_max_deceleration(boot.max_acceleration)
        hal.set_max_velocity(boot.max_velocity)
        hal.set_control_threshold(boot.control_threshold)
        yield from self._orientation(boot.orientation_check)
        hal.stop(True)
        hal.set_current(0)
        hal.set_hold_current(0)
        hal.set_brake_mode(0)
        self._set_flags(FLAGS_AT_BOOT)
        self.ready = True
        self.log.info("%s ready at 0x%02x" % (self.cfg.joint, self.cfg.address))

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
        """The stepper library's checkOrientation: +/- moves until two agree on the direction.

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
        """Drive into the end stop until |PID error| > sensitivity; STOP (BUSY cleared) aborts."""
        hal = self.hal
        hal.stop(True)
        yield _HOMING_SETTLE_MS
        homed = False
        if not self._cancelled():
            hal.set_rpm(speed if direction else -speed)
            hal.set_current(current)
            while not self._cancelled():
                if abs(hal.pid_error()) > sensitivity:
                    homed = True
                    break
                yield 1
        if homed:
            hal.set_home()
            self._clear_flags(FLAG_NOTHOMED | FLAG_STALL)
            self.log.info("homed")
        else:
            self._set_flags(FLAG_NOTHOMED)
            self.log.info("homing aborted")
        hal.stop(True)
        hal.set_current(self.drive_current)

    # Supervision.

    def _check_stall(self):
        if not self.stallguard or self.flags & (FLAG_STALL | FLAG_BUSY):
            return
        hal = self.hal
        rearms = self.stall_rearms
        stalled = self.stall.update(hal.pid_error(), hal.encoder_rpm(), self.qd_set)
        if self.trace is not None:
            self.trace(self.stall)
        if stalled and self._halt(FLAG_STALL, rearms=rearms):
            hal.stop(True)
            self.log.warn("stall detected (filtered error %.1f > threshold %.1f)"
                          % (self.stall.filtered, self.stall.threshold))

    def _check_deadman(self, now):
        """Velocity or position motion stops when the host has been silent too long."""
        if self.flags & (FLAG_NOTENABLED | FLAG_BUSY) or not (self.qd_set != 0 or self.positioning):
            return
        silent = self.clock.ticks_diff(now, self._last_host_ms)
        if silent > self.cfg.deadman_ms and self._halt(FLAG_NOTENABLED, transactions=self._seen_transactions):
            self.hal.set_rpm(0)
            self.log.warn("deadman: no I2C traffic for %d ms, motor stopped and disabled" % silent)
