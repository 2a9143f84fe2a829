"""The joint core's IRQ context: frame validation, flag updates, queueing, reply serving.

Runs inside the I2C hard IRQ (`i2c_target.py`) and must never allocate: it validates a frame with
per-register tables built from the protocol spec at boot (the same verdicts as
`Register.check_write`, one lookup and a few byte compares instead of method calls per field),
applies the command's flag changes as integer updates (so the reply already shows the command's
effect, as the original firmware's did), copies the command into a preallocated queue slot and
answers from reply bytes the main loop packed in advance.

Every readable register's reply cache is the head of its own wire buffer, `payload + flags`: a
read writes the flags into the last byte and hands the whole buffer to the port, with no copy.
"""

from ..micro import const, micropython, ptr8

QUEUE_SLOTS = const(16)  # a power of two, so slot = counter % slots survives counter wrap
# A slot: the frame, then what held when it was accepted: the flags right after it, the halt epoch
# and the stop epoch (8 bits each; a slot lives for about a millisecond).
SLOT = const(8)
SLOT_FLAGS = const(5)
SLOT_HALTS = const(6)
SLOT_STOPS = const(7)
# IRQ counters wrap here: +1 must stay a small int on 32-bit ports (largest 2**30 - 1) even before
# the mask, or the hard IRQ would allocate a long int.
COUNTER_MASK = const(0x1FFFFFFF)

# The protocol's numbers this module uses, as its own constants (viper cannot compare with another
# module's names, and the board forgets protocol.py after boot); test_irq_path checks them.
_R_NONE = const(0)
_R_UNKNOWN_REGISTER = const(1)
_R_LENGTH = const(3)
_R_VALUE = const(4)
_R_BUSY = const(5)
_R_QUEUE_FULL = const(6)
_R_DISABLED = const(7)
_R_NOT_ENABLED = const(8)
_R_STALLED = const(9)
_R_HOMING_SENSITIVITY = const(10)
_FLAG_STALL = const(0x01)
_FLAG_NOTENABLED = const(0x08)
_FLAG_ERROR = const(0x10)
_HOMEOFFSET = const(0x2E)
_STOP = const(0x29)
_SETRPM = const(0x11)
_LASTERROR = const(0x31)
MOTION_BLOCKED = const(0x09)  # FLAG_STALL | FLAG_NOTENABLED

# The frame table's layout (irq_init.py builds it at boot and documents it), as this module's
# constants for the viper code; test_irq_path checks they are irq_init's.
_REGISTERS = const(64)
REGISTER_SPACE = const(64)  # for i2c_target.py
_PRE = const(0)
FTAB_WLEN = const(64)  # for i2c_target.py
_WLEN = const(64)
_CHECK = const(128)
_SETS = const(192)
_CLEARS = const(256)
_ZERO_SETS = const(320)
_BLOCKS = const(384)
_REFUSE = const(448)
_LO = const(512)
_HI = const(768)
_LIMITS = const(1024)
_DISABLED = const(1536)
_STOPS = const(1537)
_HALTS = const(1538)
_BLOCK_IN = const(1539)
_BLOCK_OUT = const(1540)
_BLOCK_STOPS = const(1541)
_TASK = const(1542)
_TASK_STOPS = const(1543)
_HOMING_FLOOR = const(1544)
_HOMING_FLOOR_Q = const(1546)
_LAST_REASON = const(1548)  # LASTERROR's wire buffer: reason, register, count (u16), flags
_LAST_REGISTER = const(1549)
_REJECTS = const(1550)
_Q_IN = const(1553)
_Q_OUT = const(1554)
_REARMS = const(1555)
FTAB_DISABLED = const(1536)  # for loop.py and tasks.py
FTAB_HALTS = const(1538)
FTAB_BLOCK_OUT = const(1540)
FTAB_TASK = const(1542)
FTAB_TASK_STOPS = const(1543)
FTAB_REJECTS = const(1550)  # the rejection count's low byte
FTAB_Q_IN = const(1553)
FTAB_Q_OUT = const(1554)
FTAB_REARMS = const(1555)
_MOTION = const(1)
_HOMING = const(2)
_CHECK_BYTES = const(0)
_CHECK_F32 = const(1)
_CHECK_U16 = const(2)


def judge_for(core, ftab, queue_buf):
    """`core.judge`: a viper closure (its tables in cells, not looked up per call)."""

    @micropython.viper
    def judge(frame, n: int) -> int:
        """A command frame of n >= 1 bytes that is no register selection (on_frame): validated,
        its flag changes applied and queued, or rejected (recorded in LASTERROR). Returns the
        reject reason, REJECT_NONE if accepted. The legacy IRQ adapter calls it directly and keeps
        the reply selection itself; protocol v2 hands its verdict to the host. Everything it
        reads but the flags is in the frame table: no method calls, one attribute lookup."""
        f = ptr8(frame)
        t = ptr8(ftab)
        addr = f[0]
        flags = 0
        q_in = 0
        if addr >= _REGISTERS:
            reason = _R_UNKNOWN_REGISTER
        else:
            # The payload against the spec, as Register.check_write judges it.
            reason = t[_PRE + addr]
            if reason == _R_NONE and n != t[_WLEN + addr]:
                reason = _R_LENGTH
        if reason == _R_NONE:
            kind = t[_CHECK + addr]
            if kind == _CHECK_BYTES:
                lo = _LO + addr * 4 - 1
                hi = _HI + addr * 4 - 1
                i = 1
                while i < n:
                    if f[i] < t[lo + i] or f[i] > t[hi + i]:
                        reason = _R_VALUE
                    i += 1
            elif kind == _CHECK_F32:
                o = _LIMITS + addr * 8
                b3 = f[4] & 0x7F
                b2 = f[3]
                hi16 = (b3 << 8) | b2
                lo16 = (f[2] << 8) | f[1]
                low_hi = t[o] | (t[o + 1] << 8)
                low_lo = t[o + 2] | (t[o + 3] << 8)
                high_hi = t[o + 4] | (t[o + 5] << 8)
                high_lo = t[o + 6] | (t[o + 7] << 8)
                if b3 == 0x7F and b2 & 0x80:
                    reason = _R_VALUE  # NaN or infinity
                elif hi16 < low_hi or (hi16 == low_hi and lo16 < low_lo):
                    reason = _R_VALUE
                elif hi16 > high_hi or (hi16 == high_hi and lo16 > high_lo):
                    reason = _R_VALUE
            elif kind == _CHECK_U16:
                o = _LIMITS + addr * 8
                value = f[1] | (f[2] << 8)
                if value < (t[o] | (t[o + 1] << 8)) or value > (t[o + 2] | (t[o + 3] << 8)):
                    reason = _R_VALUE
        # Then the joint's state.
        if reason == _R_NONE:
            flags = int(core.flags)
            q_in = t[_Q_IN]
            stops = t[_STOPS]
            if t[_DISABLED]:
                reason = _R_DISABLED
            elif t[_BLOCKS + addr] and (
                    (t[_BLOCK_IN] != t[_BLOCK_OUT] and t[_BLOCK_STOPS] == stops)
                    or (t[_TASK] and t[_TASK_STOPS] == stops)):
                reason = _R_BUSY  # a blocking command queued or running, not cancelled by a STOP
            elif (addr != _HOMEOFFSET and addr != _STOP
                  and ((q_in - t[_Q_OUT]) & 0xFF) >= QUEUE_SLOTS):
                reason = _R_QUEUE_FULL
            else:
                # What the joint's state refuses: motion while stalled or not enabled (0 rpm
                # always goes through), HOME at or below the sensitivity noise floor.
                refuse = t[_REFUSE + addr]
                if refuse == _HOMING:
                    per_rpm = t[_HOMING_FLOOR_Q] | (t[_HOMING_FLOOR_Q + 1] << 8)
                    floor = (t[_HOMING_FLOOR] | (t[_HOMING_FLOOR + 1] << 8)) + ((f[2] * per_rpm) >> 10)
                    if f[3] <= floor:
                        reason = _R_HOMING_SENSITIVITY
                elif refuse == _MOTION:
                    if addr != _SETRPM or f[1] | f[2] | f[3] | (f[4] & 0x7F):
                        if flags & _FLAG_STALL:
                            reason = _R_STALLED
                        elif flags & _FLAG_NOTENABLED:
                            reason = _R_NOT_ENABLED
        if reason != _R_NONE:
            rejects = (t[_REJECTS] | (t[_REJECTS + 1] << 8)) + 1
            t[_LAST_REASON] = reason
            t[_LAST_REGISTER] = addr
            t[_REJECTS] = rejects & 0xFF
            t[_REJECTS + 1] = (rejects >> 8) & 0xFF
            return reason
        clears = t[_CLEARS + addr]
        before = flags
        flags = (flags | t[_SETS + addr]) & (0xFF ^ clears)
        if f[1] == 0:
            flags |= t[_ZERO_SETS + addr]
        if flags != before:  # (a store costs an attribute lookup: most commands change nothing)
            core.flags = flags
        if clears & _FLAG_STALL:
            t[_REARMS] = (t[_REARMS] + 1) & 0xFF
        if addr == _STOP:
            # Immediate, as in the original's ISR: cancels the running blocking command and any
            # motion still queued; the main loop commands 0 RPM next.
            stops = (t[_STOPS] + 1) & 0xFF
            halts = (t[_HALTS] + 1) & 0xFF
            t[_STOPS] = stops
            t[_HALTS] = halts
            core.stops = stops
            core.halts = halts
        elif addr == _HOMEOFFSET:
            cache = ptr8(core._cache[_HOMEOFFSET])
            cache[0] = f[1]
            cache[1] = f[2]
            cache[2] = f[3]
            cache[3] = f[4]
        else:
            base = (q_in & (QUEUE_SLOTS - 1)) * SLOT
            queue = ptr8(queue_buf)
            i = 0
            while i < n:
                queue[base + i] = f[i]
                i += 1
            stops = t[_STOPS]
            queue[base + SLOT_FLAGS] = flags
            queue[base + SLOT_HALTS] = t[_HALTS]
            queue[base + SLOT_STOPS] = stops
            if t[_BLOCKS + addr]:
                t[_BLOCK_STOPS] = stops
                t[_BLOCK_IN] = (t[_BLOCK_IN] + 1) & 0xFF
            t[_Q_IN] = (q_in + 1) & 0xFF
        return _R_NONE

    return judge


class IrqPath:
    """JointController's IRQ-side methods (mixed into it): no allocation anywhere here.

    A read is served from `_reply_wire`, the selected register's wire buffer (the flags go in its
    last byte, the only one of a flags-only reply), selected once when the register is written.
    """

    def host_seen(self):
        """A transaction addressed to this joint ended (feeds the deadman)."""
        self.host_us = self._ticks_us()  # when: the deadman counts from here, not from the loop
        self.transactions = (self.transactions + 1) & COUNTER_MASK

    @micropython.viper
    def on_frame(self, frame, n: int) -> int:
        """A write of n bytes (register + payload) ended. `frame` holds at most MAX_FRAME bytes.
        Selects the reply the next read gets: the register's (n == 1, a readable register), else
        the flags, with ERROR if the frame was rejected. Returns the judge's reject reason
        (REJECT_NONE: accepted, a register selection or an address probe)."""
        if n == 0:
            return _R_NONE  # address probe (bus scan)
        addr = ptr8(frame)[0]
        if n == 1 and addr < _REGISTERS:
            wire = self._wires[addr]
            if wire:
                self._reply_wire = wire
                self._reply_err = 0
                return _R_NONE
        judge = self.judge
        reason = int(judge(frame, n))
        self._reply_wire = self._flags_wire
        self._reply_err = _FLAG_ERROR if reason else 0
        return reason

    def reject_count(self):
        """Frames rejected since boot, 16 bits (LASTERROR's count). (No property: a class with one
        makes MicroPython look in the class on every attribute store, several times slower.)"""
        cache = self._cache[_LASTERROR]
        return cache[2] | (cache[3] << 8)

    def reply_wire(self):
        """The reply (payload + flags) in its wire buffer, the flags byte set now: for a link that
        sends it before anything else runs (CircuitPython's polled target), no copy."""
        wire = self._reply_wire
        wire[len(wire) - 1] = self.flags | self._reply_err
        return wire
