"""The joint core's IRQ context: frame validation, flag updates, queueing, reply serving.

Runs inside the I2C hard IRQ (`i2c_target.py`) and must never allocate: it validates a frame with
the protocol's byte-level checks, applies the command's flag changes as integer updates (so the
reply already shows the command's effect, as the original firmware's did), copies the command into
a preallocated queue slot and answers from reply bytes the main loop packed in advance.
"""

from .emitters import micropython

from .protocol import (
    BY_ADDR, FLAG_ERROR, FLAG_NOTENABLED, FLAG_STALL, HOMEOFFSET, LASTERROR, MAX_FRAME, PING, REJECT_BUSY,
    REJECT_DISABLED, REJECT_NONE, REJECT_QUEUE_FULL, REJECT_UNKNOWN_REGISTER, STOP,
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


class IrqPath:
    """JointController's IRQ-side methods (mixed into it): no allocation anywhere here.

    A read is served from `_reply_cache` (the selected register's reply bytes) and `_reply_n`
    (their count, 0 for a flags-only reply), looked up once when the register is selected.
    """

    def _init_irq_tables(self):
        """Per-address reply sizes (0: not readable), so selecting a register is one lookup."""
        sizes = bytearray(256)
        for addr in range(256):
            if self._cache[addr] is not None:
                sizes[addr] = len(self._cache[addr])
        self._rsize = sizes
        self._reply_cache = self._cache[PING]
        self._reply_n = sizes[PING]
        self._reply_err = 0

    def host_seen(self):
        """A transaction addressed to this joint ended (feeds the deadman)."""
        self.host_us = self._ticks_us()  # when: the deadman counts from here, not from the loop
        self.transactions = (self.transactions + 1) & COUNTER_MASK

    @micropython.native
    def on_frame(self, frame, n):
        """A write of n bytes (register + payload) ended. `frame` holds at most MAX_FRAME bytes."""
        if n == 0:
            return  # address probe (bus scan)
        addr = frame[0]
        if n == 1:
            size = self._rsize[addr]
            if size:
                self._reply_cache = self._cache[addr]
                self._reply_n = size
                self._reply_err = 0
                return
        reg = BY_ADDR[addr]
        if reg is None:
            self._reject(addr, REJECT_UNKNOWN_REGISTER)
            return
        reason = reg.check_write(frame, 1, n - 1)
        if reason == REJECT_NONE:
            if self.disabled:
                reason = REJECT_DISABLED
            elif reg.blocking and self._blocking_live():
                reason = REJECT_BUSY
            elif (addr != HOMEOFFSET and addr != STOP
                  and ((self._q_in - self._q_out) & COUNTER_MASK) >= QUEUE_SLOTS):
                reason = REJECT_QUEUE_FULL
            else:
                reason = self._refusal(addr, frame)  # supervise.py: motion in this state, HOME limits
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
            base = (self._q_in % QUEUE_SLOTS) * SLOT
            queue = self._queue
            for i in range(n):
                queue[base + i] = frame[i]
            queue[base + SLOT_FLAGS] = flags
            queue[base + SLOT_HALTS] = self.halts
            queue[base + SLOT_STOPS] = self.stops
            if reg.blocking:
                self._blocking_stops = self.stops
                self._blocking_in = (self._blocking_in + 1) & COUNTER_MASK
            self._q_in = (self._q_in + 1) & COUNTER_MASK
        self._reply_n = 0
        self._reply_err = 0

    def _blocking_live(self):
        """A blocking command is queued or running and no STOP has cancelled it."""
        if self._blocking_in != self._blocking_out and self._blocking_stops == self.stops:
            return True
        return self._task is not None and self._task_stops == self.stops

    def _reject(self, addr, reason):
        self._reply_n = 0
        self._reply_err = FLAG_ERROR
        self.rejects = (self.rejects + 1) & 0xFFFF
        cache = self._cache[LASTERROR]
        cache[0] = reason
        cache[1] = addr
        cache[2] = self.rejects & 0xFF
        cache[3] = self.rejects >> 8

    @micropython.native
    def reply_into(self, out):
        """Write the reply (payload + flags) right-aligned at the end of `out`; return its length."""
        end = len(out) - 1
        out[end] = self.flags | self._reply_err
        n = self._reply_n
        if n:
            cache = self._reply_cache
            start = end - n
            for i in range(n):
                out[start + i] = cache[i]
        return n + 1
