"""Protocol v2's memory map served on the joint (MemLink, see v2.py for how it works): loaded when a
host first asks for v2, so a joint serving the legacy map keeps neither this nor protocol_v2.py.

Allocation-free once constructed (tests run it with the heap locked under MicroPython).
"""

from .protocol import ANGLEMOVED, GETENCODERRPM, LASTERROR
from . import protocol_v2 as V
from .fixed import f32_to_q
from .i2c_target import IRQ_END_WRITE
from .irq import COUNTER_MASK  # counters wrap before they would become long ints
from .regtable import NOT_A_COMMAND

try:
    from micropython import const
except ImportError:
    def const(value):
        return value

_EMPTY_CMD = const(0xFF)  # no register 0xFF: a mailbox the host has not written since the swap
_EMPTY_SEQ = const(0x80)  # bit 7 set: never a sequence number the host sends


def f32_to_fixed(buf, off, q, limit):
    """round(float32 at buf[off:] x 2**q), saturated to +/-limit. Integer arithmetic only."""
    value = f32_to_q(buf, off, q)
    if value > limit:
        return limit
    if value < -limit:
        return -limit
    return value


class MemLink:
    """Protocol v2 for one joint: create it, serve `mem` with an `I2CTarget(mem=..., mem_addrsize=0)`,
    then `attach` that target and its activity probe."""

    def __init__(self, core, address, critical):
        self._core = core
        self._address = address
        self._irq_off, self._irq_on = critical
        self._bus_active = None
        self.target = None
        self.mem = bytearray(V.MEM_SIZE)
        view = memoryview(self.mem)
        self._mailbox = view[V.MAILBOX:V.MAILBOX + V.MAILBOX_SIZE]
        self._state = view[V.STATE:V.STATE + V.STATE_SIZE]
        self._empty = bytearray(V.MAILBOX_SIZE)
        for i in range(V.MAILBOX_SIZE):
            self._empty[i] = _EMPTY_CMD
        self._empty[V.M_SEQ] = _EMPTY_SEQ
        self._rx = bytearray(V.MAILBOX_SIZE)
        self._last = bytearray(self._empty)  # the last frame accepted (retries are ignored)
        self._staged = bytearray(V.STATE_SIZE)
        self._published = bytearray(V.STATE_SIZE)
        self._seen_state = bytearray(V.STATE_SIZE)
        self._frame = bytearray(1 + V.PAYLOAD_SIZE)
        self._mailbox[:] = self._empty
        self.ack = 0
        self.verdict = V.REASON_OK
        # Link statistics (the joint's side): every frame taken, and why each was not applied.
        self.writes = 0  # END_WRITE events (soft IRQ): frames, polls, probes
        self._seen_writes = 0
        self.frames = 0
        self.applied = 0
        self.polls = 0
        self.retries = 0
        self.crc_errors = 0
        self.sequence_errors = 0
        self.frame_errors = 0
        self.rejected = 0  # passed the link checks, refused by the command's own checks
        self.deferred = 0  # swaps postponed because a transaction was in progress
        self.last_write_ms = core.clock.ticks_ms()
        self.applied_writes = 0  # `writes` when the last frame was applied
        self._pack()
        self._published[:] = self._staged
        self._state[:] = self._staged
        self._on_write = self._count_write  # bound once: the soft IRQ must not build it

    def attach(self, target, bus_active):
        self.target = target
        self._bus_active = bus_active
        target.irq(self._on_write, trigger=IRQ_END_WRITE, hard=False)

    def detach(self):
        if self.target is not None:
            self.target.irq(None, trigger=0, hard=False)
            self.target = None

    def _count_write(self, target):
        self.writes = (self.writes + 1) & COUNTER_MASK

    # ---- main loop ----

    def poll(self):
        """Exchange mailbox and state with the bus and judge what arrived; False if the bus was
        busy (the swap is retried at the next poll)."""
        if self.writes != self._seen_writes:
            self._seen_writes = self.writes
            self.last_write_ms = self._core.clock.ticks_ms()
            self._core.host_seen()
        for _ in range(2):
            self._pack()
            took = self._swap()
            if took < 0:
                self.deferred = (self.deferred + 1) & COUNTER_MASK
                return False
            if not took:
                return True
            self._judge(took == 2)
        return True

    def _swap(self):
        """-1: bus busy; 0: published, no frame; 1: frame taken; 2: frame taken, host overflowed."""
        # Interrupts go off only while the bus is idle: the rp2 driver handles a repeated START
        # before the RX data that came with it, so a mailbox byte still in the FIFO then (the
        # I2C IRQ held off for a bit time at the end of a write) is stored at offset 0 and the
        # read starts past the state block's first byte (chip/README.md). A transaction that
        # starts during the short section below is still far from the end of its write then.
        if self._bus_active():
            return -1
        state = self._irq_off()
        if self._bus_active():
            self._irq_on(state)
            return -1
        self._seen_state[:] = self._state
        self._rx[:] = self._mailbox
        self._mailbox[:] = self._empty
        self._state[:] = self._staged
        self._irq_on(state)
        overflow = self._seen_state != self._published
        self._published[:] = self._staged
        if self._rx == self._empty:
            return 2 if overflow else 0
        return 2 if overflow else 1

    def _judge(self, overflow):
        rx = self._rx
        self.frames = (self.frames + 1) & COUNTER_MASK
        if overflow or rx[V.M_SEQ] & _EMPTY_SEQ:
            self.frame_errors = (self.frame_errors + 1) & COUNTER_MASK
            self.verdict = V.REASON_FRAME
            return
        if V.mailbox_crc(rx, 0, self._address) != rx[V.M_CRC]:
            self.crc_errors = (self.crc_errors + 1) & COUNTER_MASK
            self.verdict = V.REASON_CRC
            return
        ahead = (rx[V.M_SEQ] - self.ack) & V.SEQ_MASK
        if ahead == 0 and rx == self._last:
            self.retries = (self.retries + 1) & COUNTER_MASK  # the host retried a transfer: applied once, verdict unchanged
            return
        if ahead == 0 or ahead >= V.SEQ_WINDOW:
            self.sequence_errors = (self.sequence_errors + 1) & COUNTER_MASK
            self.verdict = V.REASON_SEQUENCE
            return
        self.ack = rx[V.M_SEQ]
        self._last[:] = rx
        self.verdict = self._apply(rx)
        self.applied_writes = self.writes
        if self.verdict == V.REASON_OK:
            if rx[V.M_CMD] == V.CMD_NONE:
                self.polls = (self.polls + 1) & COUNTER_MASK
            else:
                self.applied = (self.applied + 1) & COUNTER_MASK
        else:
            self.rejected = (self.rejected + 1) & COUNTER_MASK

    def _apply(self, rx):
        cmd = rx[V.M_CMD]
        if cmd == V.CMD_NONE:
            return V.REASON_OK
        n = self._core.registers.command_size(cmd)
        if n == NOT_A_COMMAND:
            return V.REASON_COMMAND
        for i in range(V.M_PAYLOAD + n, V.M_PAYLOAD + V.PAYLOAD_SIZE):
            if rx[i]:
                return V.REASON_VALUE  # the padding must be zero
        frame = self._frame
        frame[0] = cmd
        for i in range(n):
            frame[1 + i] = rx[V.M_PAYLOAD + i]
        core = self._core
        before = core.rejects
        core.on_frame(frame, 1 + n)
        if core.rejects == before:
            return V.REASON_OK
        return V.FROM_LEGACY[core.cached_reply(LASTERROR)[0]]

    def _pack(self):
        core = self._core
        out = self._staged
        out[0] = (V.STATUS_MARKER | (self.verdict << V.REASON_SHIFT)
                  | (core.flags & V.STATUS_FLAGS))
        pos = f32_to_fixed(core.cached_reply(ANGLEMOVED), 0, V.POSITION_Q, V.POSITION_MAX)
        vel = f32_to_fixed(core.cached_reply(GETENCODERRPM), 0, V.VELOCITY_Q, V.VELOCITY_MAX)
        p = V.S_POSITION - V.STATE
        out[p] = pos & 0xFF
        out[p + 1] = (pos >> 8) & 0xFF
        out[p + 2] = (pos >> 16) & 0xFF
        v = V.S_VELOCITY - V.STATE
        out[v] = vel & 0xFF
        out[v + 1] = V.VELOCITY_MARKER | ((vel >> 8) & 0x7F)
        out[V.S_ACK - V.STATE] = self.ack
        out[V.S_CRC - V.STATE] = V.state_crc(out, 0, self._address)
