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

from array import array

from .emitters import micropython

from .protocol import (
    BY_ADDR, F32, FLAG_ERROR, FLAG_NOTENABLED, FLAG_STALL, HOMEOFFSET, I32, LASTERROR, MAX_FRAME,
    PING, REJECT_BUSY, REJECT_DISABLED, REJECT_LENGTH, REJECT_NONE, REJECT_QUEUE_FULL,
    REJECT_UNKNOWN_REGISTER, REJECT_UNSUPPORTED, REJECT_VALUE, STOP, U8, U16,
)

try:
    from micropython import const
except ImportError:
    def const(value):
        return value

QUEUE_SLOTS = const(16)  # a power of two, so slot = counter % slots survives counter wrap
# A slot: the frame, then what held when it was accepted: the flags right after it, the halt epoch
# and the stop epoch (8 bits each; a slot lives for about a millisecond).
SLOT = MAX_FRAME + 3
SLOT_FLAGS = MAX_FRAME
SLOT_HALTS = MAX_FRAME + 1
SLOT_STOPS = MAX_FRAME + 2
MOTION_BLOCKED = FLAG_STALL | FLAG_NOTENABLED
# IRQ counters wrap here: +1 must stay a small int on 32-bit ports (largest 2**30 - 1) even before
# the mask, or the hard IRQ would allocate a long int.
COUNTER_MASK = const(0x1FFFFFFF)

# How a register's payload is checked (the `_check` table).
CHECK_BYTES = const(0)  # every field U8 (or none): each byte within [_lo, _hi] at addr*4 + i
CHECK_F32 = const(1)  # one F32 field: finite, |value| within the halves at addr*4 in _f32
CHECK_U16 = const(2)  # one U16 field: within [_lo16, _hi16]
CHECK_ANY = const(3)  # one I32 field: any value
CHECK_SPEC = const(4)  # any other layout: Register.check_write itself


def _payload_check(reg):
    """The check kind for a register's write fields."""
    kinds = [f.kind for f in reg.write]
    if all(k == U8 for k in kinds) and reg.wsize <= 4:
        return CHECK_BYTES
    if kinds == [F32]:
        return CHECK_F32
    if kinds == [U16]:
        return CHECK_U16
    if kinds == [I32]:
        return CHECK_ANY
    return CHECK_SPEC


class IrqPath:
    """JointController's IRQ-side methods (mixed into it): no allocation anywhere here.

    A read is served from `_reply_tails`, the suffixes of the selected register's wire buffer
    ([0] is all of it; the flags go in its last byte, the only one of a flags-only reply), selected
    once when the register is written.
    """

    def _init_irq_tables(self):
        """Wire buffers for the reply caches and the per-register frame tables, from the spec."""
        self._wire_tails = [None] * 256
        for addr in range(256):
            cache = self._cache[addr]
            if cache is not None:
                n = len(cache)
                wire = bytearray(n + 1)
                wire[:n] = cache
                view = memoryview(wire)
                self._cache[addr] = view[:n]  # the main loop packs here, as before
                self._wire_tails[addr] = [view[i:] for i in range(n + 1)]
        flags_only = memoryview(bytearray(1))
        self._flags_tails = [flags_only]
        # Frame verdicts by register: the reject reason whatever the payload (or REJECT_NONE),
        # the frame length a payload needs, and the spec's flag effects.
        self._pre = bytearray(256)
        self._wlen = bytearray(256)
        self._check = bytearray(256)
        self._lo = bytearray(1024)
        self._hi = bytearray(1024)
        self._f32 = array("H", [0] * 1024)
        self._sets = bytearray(256)
        self._clears = bytearray(256)
        self._zero_sets = bytearray(256)
        self._blocks = bytearray(256)
        for addr in range(256):
            reg = BY_ADDR[addr]
            if reg is None:
                self._pre[addr] = REJECT_UNKNOWN_REGISTER
                continue
            if not reg.supported:
                self._pre[addr] = REJECT_UNSUPPORTED
                continue
            if reg.wsize == 0:
                self._pre[addr] = REJECT_LENGTH
                continue
            self._wlen[addr] = 1 + reg.wsize
            kind = _payload_check(reg)
            self._check[addr] = kind
            base = addr * 4
            if kind == CHECK_BYTES:
                for i, f in enumerate(reg.write):
                    self._lo[base + i] = f.lo
                    self._hi[base + i] = f.hi
            elif kind == CHECK_F32:
                f = reg.write[0]
                self._f32[base] = f._lo_hi16
                self._f32[base + 1] = f._lo_lo16
                self._f32[base + 2] = f._hi_hi16
                self._f32[base + 3] = f._hi_lo16
            elif kind == CHECK_U16:
                self._f32[base] = reg.write[0].lo
                self._f32[base + 1] = reg.write[0].hi
            self._sets[addr] = reg.sets
            self._clears[addr] = reg.clears
            self._zero_sets[addr] = reg.zero_sets
            self._blocks[addr] = reg.blocking
        self._reply_tails = self._wire_tails[PING]
        self._reply_err = 0

    def host_seen(self):
        """A transaction addressed to this joint ended (feeds the deadman)."""
        self.host_us = self._ticks_us()  # when: the deadman counts from here, not from the loop
        self.transactions = (self.transactions + 1) & COUNTER_MASK

    @micropython.native
    def _payload_reason(self, addr, frame, n):
        """REJECT_NONE if the n-byte frame is a valid write of register `addr`, else why not."""
        reason = self._pre[addr]
        if reason != REJECT_NONE:
            return reason
        if n != self._wlen[addr]:
            return REJECT_LENGTH
        kind = self._check[addr]
        base = addr * 4
        if kind == CHECK_BYTES:
            lo = self._lo
            hi = self._hi
            for i in range(n - 1):
                b = frame[1 + i]
                if b < lo[base + i] or b > hi[base + i]:
                    return REJECT_VALUE
            return REJECT_NONE
        if kind == CHECK_F32:
            b3 = frame[4] & 0x7F
            b2 = frame[3]
            if b3 == 0x7F and b2 & 0x80:
                return REJECT_VALUE  # NaN or infinity
            hi16 = (b3 << 8) | b2
            lo16 = (frame[2] << 8) | frame[1]
            t = self._f32
            if hi16 < t[base] or (hi16 == t[base] and lo16 < t[base + 1]):
                return REJECT_VALUE
            if hi16 > t[base + 2] or (hi16 == t[base + 2] and lo16 > t[base + 3]):
                return REJECT_VALUE
            return REJECT_NONE
        if kind == CHECK_U16:
            value = frame[1] | (frame[2] << 8)
            if value < self._f32[base] or value > self._f32[base + 1]:
                return REJECT_VALUE
            return REJECT_NONE
        if kind == CHECK_ANY:
            return REJECT_NONE
        return BY_ADDR[addr].check_write(frame, 1, n - 1)

    @micropython.native
    def on_frame(self, frame, n):
        """A write of n bytes (register + payload) ended. `frame` holds at most MAX_FRAME bytes."""
        if n == 0:
            return  # address probe (bus scan)
        addr = frame[0]
        if n == 1:
            tails = self._wire_tails[addr]
            if tails is not None:
                self._reply_tails = tails
                self._reply_err = 0
                return
        reason = self._payload_reason(addr, frame, n)
        if reason == REJECT_NONE:
            if self.disabled:
                reason = REJECT_DISABLED
            elif self._blocks[addr] and self._blocking_live():
                reason = REJECT_BUSY
            elif (addr != HOMEOFFSET and addr != STOP
                  and ((self._q_in - self._q_out) & COUNTER_MASK) >= QUEUE_SLOTS):
                reason = REJECT_QUEUE_FULL
            else:
                reason = self._refusal(addr, frame)  # core.py: motion in this state, HOME limits
        if reason != REJECT_NONE:
            self._reject(addr, reason)
            return
        flags = (self.flags | self._sets[addr]) & ~self._clears[addr]
        if frame[1] == 0:
            flags |= self._zero_sets[addr]
        self.flags = flags
        if self._clears[addr] & FLAG_STALL:
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
            base = (self._q_in % QUEUE_SLOTS) * SLOT
            queue = self._queue
            for i in range(n):
                queue[base + i] = frame[i]
            queue[base + SLOT_FLAGS] = flags
            queue[base + SLOT_HALTS] = self.halts
            queue[base + SLOT_STOPS] = self.stops
            if self._blocks[addr]:
                self._blocking_stops = self.stops
                self._blocking_in = (self._blocking_in + 1) & COUNTER_MASK
            self._q_in = (self._q_in + 1) & COUNTER_MASK
        self._reply_tails = self._flags_tails
        self._reply_err = 0

    def _blocking_live(self):
        """A blocking command is queued or running and no STOP has cancelled it."""
        if self._blocking_in != self._blocking_out and self._blocking_stops == self.stops:
            return True
        return self._task is not None and self._task_stops == self.stops

    def _reject(self, addr, reason):
        self._reply_tails = self._flags_tails
        self._reply_err = FLAG_ERROR
        self.rejects = (self.rejects + 1) & 0xFFFF
        cache = self._cache[LASTERROR]
        cache[0] = reason
        cache[1] = addr
        cache[2] = self.rejects & 0xFF
        cache[3] = self.rejects >> 8

    @micropython.native
    def reply_wire(self):
        """The selected reply, flags included as of now: (its wire buffer's suffixes, its length)."""
        tails = self._reply_tails
        n = len(tails) - 1
        tails[0][n] = self.flags | self._reply_err
        return n + 1

    @micropython.native
    def reply_into(self, out):
        """Write the reply (payload + flags) right-aligned at the end of `out`; return its length."""
        n = self.reply_wire()
        wire = self._reply_tails[0]
        start = len(out) - n
        for i in range(n):
            out[start + i] = wire[i]
        return n
