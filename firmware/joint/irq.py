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

from .emitters import micropython, ptr8

from .protocol import (
    F32, FLAG_ERROR, FLAG_NOTENABLED, FLAG_STALL, HOMEOFFSET, I32, LASTERROR, MAX_FRAME,
    HOME, MOVEANGLE, MOVESTEPS, MOVETOANGLE, PING, REJECT_BUSY, REJECT_DISABLED,
    REJECT_HOMING_SENSITIVITY, REJECT_LENGTH, REJECT_NONE, REJECT_NOT_ENABLED, REJECT_QUEUE_FULL,
    REJECT_STALLED, REJECT_UNKNOWN_REGISTER, REJECT_UNSUPPORTED, REJECT_VALUE, SETRPM, STOP, U8, U16,
)

try:
    from micropython import const
except ImportError:
    def const(value):
        return value

QUEUE_SLOTS = const(16)  # a power of two, so slot = counter % slots survives counter wrap
# A slot: the frame, then what held when it was accepted: the flags right after it, the halt epoch
# and the stop epoch (8 bits each; a slot lives for about a millisecond).
SLOT = const(8)
SLOT_FLAGS = const(5)
SLOT_HALTS = const(6)
SLOT_STOPS = const(7)
MOTION_BLOCKED = FLAG_STALL | FLAG_NOTENABLED
# IRQ counters wrap here: +1 must stay a small int on 32-bit ports (largest 2**30 - 1) even before
# the mask, or the hard IRQ would allocate a long int.
COUNTER_MASK = const(0x1FFFFFFF)

# The protocol's numbers the viper code compares with, as constants of this module (viper cannot
# compare with another module's names); checked against protocol.py below.
_R_NONE = const(0)
_R_UNKNOWN_REGISTER = const(1)
_R_LENGTH = const(3)
_R_VALUE = const(4)
_R_BUSY = const(5)
_R_QUEUE_FULL = const(6)
_R_DISABLED = const(7)
_FLAG_STALL = const(0x01)
_R_NOT_ENABLED = const(8)
_R_STALLED = const(9)
_R_HOMING_SENSITIVITY = const(10)
_FLAG_NOTENABLED = const(0x08)
_HOMEOFFSET = const(0x2E)
_STOP = const(0x29)
_SETRPM = const(0x11)
_FLAG_ERROR = const(0x10)
if ((_R_NONE, _R_UNKNOWN_REGISTER, _R_LENGTH, _R_VALUE, _R_BUSY, _R_QUEUE_FULL, _R_DISABLED,
     _R_NOT_ENABLED, _R_STALLED, _R_HOMING_SENSITIVITY, _FLAG_STALL, _FLAG_NOTENABLED, _HOMEOFFSET,
     _STOP, _SETRPM, SLOT_FLAGS, SLOT, _FLAG_ERROR)
        != (REJECT_NONE, REJECT_UNKNOWN_REGISTER, REJECT_LENGTH, REJECT_VALUE, REJECT_BUSY,
            REJECT_QUEUE_FULL, REJECT_DISABLED, REJECT_NOT_ENABLED, REJECT_STALLED,
            REJECT_HOMING_SENSITIVITY, FLAG_STALL, FLAG_NOTENABLED, HOMEOFFSET, STOP, SETRPM,
            MAX_FRAME, MAX_FRAME + 3, FLAG_ERROR)):
    raise ImportError("irq.py constants differ from protocol.py")

# The frame table (`_ftab`, one bytearray so viper code reaches it through one pointer): by register
# address (every register is below _REGISTERS; any other address is unknown), the reject reason
# whatever the payload (or REJECT_NONE), the frame length a payload needs, how the payload is
# checked, the spec's flag effects, what the joint's state may refuse, then the payload limits.
_REGISTERS = const(64)
REGISTER_SPACE = const(64)  # for i2c_target.py
_PRE = const(0)
_WLEN = const(64)
FTAB_WLEN = const(64)  # for i2c_target.py
_CHECK = const(128)
_SETS = const(192)
_CLEARS = const(256)
_ZERO_SETS = const(320)
_BLOCKS = const(384)
_REFUSE = const(448)  # _MOTION or _HOMING
_LO = const(512)  # CHECK_BYTES: payload byte i within [_LO, _HI] at addr*4 + i
_HI = const(768)
_LIMITS = const(1024)  # CHECK_F32: the |value| limits as 16-bit halves (low high16, low low16,
#                        high high16, high low16), little-endian, at addr*8; CHECK_U16: low, high
# State bytes mirrored from the core's attributes where they are written (a byte here costs the
# viper code no lookup): 1 if the joint is disabled; the stop and halt epochs.
_DISABLED = const(1536)
_STOPS = const(1537)
_HALTS = const(1538)
FTAB_DISABLED = const(1536)  # for loop.py
FTAB_HALTS = const(1538)
_FTAB_SIZE = const(1539)
_MOTION = const(1)  # refused while stalled or not enabled (SETRPM: unless 0 rpm)
_HOMING = const(2)  # refused at or below the homing sensitivity noise floor

CHECK_BYTES = const(0)  # every field U8
CHECK_F32 = const(1)  # one F32 field: finite, |value| within the limits
CHECK_U16 = const(2)  # one U16 field
CHECK_ANY = const(3)  # one I32 field: any value


def _payload_check(reg):
    """The check kind for a register's write fields; ValueError if the tables cannot check them."""
    kinds = [f.kind for f in reg.write]
    if all(k == U8 for k in kinds) and len(kinds) <= 4:
        return CHECK_BYTES
    if kinds == [F32]:
        return CHECK_F32
    if kinds == [U16]:
        return CHECK_U16
    if kinds == [I32]:
        return CHECK_ANY
    raise ValueError("the IRQ frame tables cannot check register %s" % reg.name)


def _put16(table, off, value):
    table[off] = value & 0xFF
    table[off + 1] = value >> 8


def frame_table():
    """The frame table (layout above) for the protocol's registers."""
    from .protocol import BY_ADDR  # at boot only: the board forgets the spec's objects after boot
    t = bytearray(_FTAB_SIZE)
    for addr in range(256):
        reg = BY_ADDR[addr]
        if addr >= _REGISTERS:
            if reg is not None:
                raise ValueError("register %s is outside the IRQ frame table" % reg.name)
        elif reg is None:
            t[_PRE + addr] = REJECT_UNKNOWN_REGISTER
        elif not reg.supported:
            t[_PRE + addr] = REJECT_UNSUPPORTED
        elif reg.wsize == 0:
            t[_PRE + addr] = REJECT_LENGTH
        else:
            kind = _payload_check(reg)
            t[_WLEN + addr] = 1 + reg.wsize
            t[_CHECK + addr] = kind
            t[_SETS + addr] = reg.sets
            t[_CLEARS + addr] = reg.clears
            t[_ZERO_SETS + addr] = reg.zero_sets
            t[_BLOCKS + addr] = reg.blocking
            if addr in (SETRPM, MOVETOANGLE, MOVEANGLE, MOVESTEPS):
                t[_REFUSE + addr] = _MOTION
            elif addr == HOME:
                t[_REFUSE + addr] = _HOMING
            if kind == CHECK_BYTES:
                for i, f in enumerate(reg.write):
                    t[_LO + addr * 4 + i] = f.lo
                    t[_HI + addr * 4 + i] = f.hi
            elif kind == CHECK_F32:
                f = reg.write[0]
                for i, half in enumerate((f._lo_hi16, f._lo_lo16, f._hi_hi16, f._hi_lo16)):
                    _put16(t, _LIMITS + addr * 8 + 2 * i, half)
            elif kind == CHECK_U16:
                _put16(t, _LIMITS + addr * 8, reg.write[0].lo)
                _put16(t, _LIMITS + addr * 8 + 2, reg.write[0].hi)
    return t


def _judge_for(core, ftab, queue_buf):
    """`core.judge`: a viper closure (its tables in cells, not looked up per call)."""

    @micropython.viper
    def judge(frame, n: int) -> int:
        """A command frame of n >= 1 bytes that is no register selection (on_frame): validated,
        its flag changes applied and queued, or rejected (LASTERROR). Returns the reject reason,
        REJECT_NONE if accepted. The legacy IRQ adapter calls it directly and keeps the reply
        selection itself."""
        f = ptr8(frame)
        addr = f[0]
        if addr >= _REGISTERS:
            core._reject(addr, _R_UNKNOWN_REGISTER)
            return _R_UNKNOWN_REGISTER
        t = ptr8(ftab)
        # The payload against the spec, as Register.check_write judges it.
        reason = t[_PRE + addr]
        if reason == _R_NONE and n != t[_WLEN + addr]:
            reason = _R_LENGTH
        if reason == _R_NONE:
            kind = t[_CHECK + addr]
            if kind == CHECK_BYTES:
                lo = _LO + addr * 4 - 1
                hi = _HI + addr * 4 - 1
                i = 1
                while i < n:
                    if f[i] < t[lo + i] or f[i] > t[hi + i]:
                        reason = _R_VALUE
                    i += 1
            elif kind == CHECK_F32:
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
            elif kind == CHECK_U16:
                o = _LIMITS + addr * 8
                value = f[1] | (f[2] << 8)
                if value < (t[o] | (t[o + 1] << 8)) or value > (t[o + 2] | (t[o + 3] << 8)):
                    reason = _R_VALUE
        # Then the joint's state.
        flags = int(core.flags)
        q_in = int(core._q_in)
        if reason == _R_NONE:
            if t[_DISABLED]:
                reason = _R_DISABLED
            elif t[_BLOCKS + addr] and bool(core._blocking_live()):
                reason = _R_BUSY
            elif (addr != _HOMEOFFSET and addr != _STOP
                  and ((q_in - int(core._q_out)) & COUNTER_MASK) >= QUEUE_SLOTS):
                reason = _R_QUEUE_FULL
            else:
                # What the joint's state refuses: motion while stalled or not enabled (0 rpm
                # always goes through), HOME at or below the sensitivity noise floor.
                refuse = t[_REFUSE + addr]
                if refuse == _HOMING:
                    floor = int(core._homing_floor) + ((f[2] * int(core._homing_floor_q)) >> 10)
                    if f[3] <= floor:
                        reason = _R_HOMING_SENSITIVITY
                elif refuse == _MOTION:
                    if addr != _SETRPM or f[1] | f[2] | f[3] | (f[4] & 0x7F):
                        if flags & _FLAG_STALL:
                            reason = _R_STALLED
                        elif flags & _FLAG_NOTENABLED:
                            reason = _R_NOT_ENABLED
        if reason != _R_NONE:
            core._reject(addr, reason)
            return reason
        clears = t[_CLEARS + addr]
        before = flags
        flags = (flags | t[_SETS + addr]) & (0xFF ^ clears)
        if f[1] == 0:
            flags |= t[_ZERO_SETS + addr]
        if flags != before:  # (a store costs an attribute lookup: most commands change nothing)
            core.flags = flags
        if clears & _FLAG_STALL:
            core.stall_rearms = (int(core.stall_rearms) + 1) & 0xFF
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
                core._blocking_stops = stops
                core._blocking_in = (int(core._blocking_in) + 1) & COUNTER_MASK
            core._q_in = (q_in + 1) & COUNTER_MASK
        return _R_NONE

    return judge


class IrqPath:
    """JointController's IRQ-side methods (mixed into it): no allocation anywhere here.

    A read is served from `_reply_wire`, the selected register's wire buffer (the flags go in its
    last byte, the only one of a flags-only reply), selected once when the register is written.
    """

    def _init_irq_tables(self):
        """Wire buffers for the reply caches and the per-register frame tables, from the spec."""
        self._wires = [None] * _REGISTERS
        for addr in range(len(self._cache)):
            cache = self._cache[addr]
            if cache is not None:
                n = len(cache)
                wire = bytearray(n + 1)
                wire[:n] = cache
                view = memoryview(wire)
                self._cache[addr] = view[:n]  # the main loop packs here, as before
                self._wires[addr] = view
        self._flags_wire = memoryview(bytearray(1))
        self._ftab = frame_table()
        self._ftab[FTAB_DISABLED] = 1 if self.disabled else 0
        self._queue = bytearray(QUEUE_SLOTS * SLOT)
        self.judge = _judge_for(self, self._ftab, self._queue)
        self._reply_wire = self._wires[PING]
        self._reply_err = 0

    def host_seen(self):
        """A transaction addressed to this joint ended (feeds the deadman)."""
        self.host_us = self._ticks_us()  # when: the deadman counts from here, not from the loop
        self.transactions = (self.transactions + 1) & COUNTER_MASK

    @micropython.viper
    def on_frame(self, frame, n: int):
        """A write of n bytes (register + payload) ended. `frame` holds at most MAX_FRAME bytes.
        Selects the reply the next read gets: the register's (n == 1, a readable register), else
        the flags, with ERROR if the frame was rejected."""
        if n == 0:
            return  # address probe (bus scan)
        addr = ptr8(frame)[0]
        if n == 1 and addr < _REGISTERS:
            wire = self._wires[addr]
            if wire:
                self._reply_wire = wire
                self._reply_err = 0
                return
        judge = self.judge
        reason = int(judge(frame, n))
        self._reply_wire = self._flags_wire
        self._reply_err = _FLAG_ERROR if reason else 0

    def _blocking_live(self):
        """A blocking command is queued or running and no STOP has cancelled it."""
        if self._blocking_in != self._blocking_out and self._blocking_stops == self.stops:
            return True
        return self._task is not None and self._task_stops == self.stops

    def _reject(self, addr, reason):
        self.rejects = (self.rejects + 1) & 0xFFFF
        cache = self._cache[LASTERROR]
        cache[0] = reason
        cache[1] = addr
        cache[2] = self.rejects & 0xFF
        cache[3] = self.rejects >> 8

    @micropython.native
    def reply_into(self, out):
        """Write the reply (payload + flags) right-aligned at the end of `out`; return its length."""
        wire = self._reply_wire
        n = len(wire)
        wire[n - 1] = self.flags | self._reply_err
        start = len(out) - n
        for i in range(n):
            out[start + i] = wire[i]
        return n
