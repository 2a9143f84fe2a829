"""Protocol v2 on the joint: the memory map of protocol_v2.py served by `I2CTarget(mem=...)`, and
the switch between the legacy register map and v2.

`MemLink` runs in the main loop only; the peripheral's C code serves the bus byte by byte from
`mem` with no Python while SCL is held. Each `poll()`:

1. packs the next state block into a staging buffer (integers only: the position and velocity are
   the values behind the legacy ANGLEMOVED / GETENCODERRPM reply caches, `core.reply_values`,
   rescaled from Q12 / Q16);
2. swaps, in one short critical section entered only while no transaction is in progress (the
   peripheral's activity bit, checked before and inside it: interrupts held off across the end
   of a write phase shift the rp2 transfer): takes the last frame out of the inbox, where the
   END_WRITE handler moved the mailbox each write left (emptying it, so the next write lands on an
   empty mailbox and two writes are never judged as one frame, whatever the loop's timing), notes
   whether the host wrote past it into the state block, and publishes the staged block. A read
   therefore always sees one whole block, and the mailbox is never taken half-written;
3. judges the frame it took: framing, CRC, sequence number, then the legacy register's own checks
   by the core's judge (`core.judge`), exactly as a legacy write of that register is judged; its
   reject reason is the verdict. The verdict and the new `ack` go out with the next swap, in the
   same poll.

Allocation-free once constructed (tests run it with the heap locked under MicroPython).
"""

import gc

from ..spec.protocol_v2 import (  # numbers and tables only: the board forgets protocol_v2 after boot
    CRC_TABLE, CMD_NONE, FROM_LEGACY, MAILBOX, MAILBOX_SIZE, MEM_SIZE, M_CMD, M_CRC, M_PAYLOAD,
    M_SEQ, PAYLOAD_SIZE, POSITION_MAX, POSITION_Q, PROTOCOL_LEGACY, PROTOCOL_V2, REASON_COMMAND,
    REASON_CRC, REASON_FRAME, REASON_OK, REASON_SEQUENCE, REASON_SHIFT, REASON_VALUE, SEQ_MASK,
    SEQ_WINDOW, SILENCE_MS, STATE, STATE_SIZE, STATUS_FLAGS, STATUS_MARKER, S_ACK, S_CRC,
    S_POSITION, S_VELOCITY, VELOCITY_MARKER, VELOCITY_MAX, VELOCITY_Q,
)
from ..motion.fixed import ANGLE_Q, RPM_Q, rescale
from .i2c_target import IRQ_END_WRITE
from ..core.irq import COUNTER_MASK  # counters wrap before they would become long ints
from ..spec.regtable import NOT_A_COMMAND
from ..micro import const

_EMPTY_CMD = const(0xFF)  # no register 0xFF: a mailbox the host has not written since the swap
_EMPTY_SEQ = const(0x80)  # bit 7 set: never a sequence number the host sends
_ROOM = const(16384)  # bytes free before a protocol switch (its allocations take about 1 KB)


def _mailbox_crc(buf, address):
    """protocol_v2.mailbox_crc of the mailbox at buf[0:] (its loop, over its table)."""
    table = CRC_TABLE
    crc = table[address << 1]
    for i in range(M_CMD, M_CRC):
        crc = table[crc ^ buf[i]]
    return table[crc ^ buf[M_SEQ]]


def _state_crc(buf, address):
    """protocol_v2.state_crc of the state block at buf[0:]."""
    table = CRC_TABLE
    crc = table[(address << 1) | 1]
    for i in range(STATE_SIZE - 1):
        crc = table[crc ^ buf[i]]
    return crc


class MemLink:
    """Protocol v2 for one joint: create it, serve `mem` with an `I2CTarget(mem=..., mem_addrsize=0)`,
    then `attach` that target and its activity probe."""

    def __init__(self, core, address, critical):
        self._core = core
        self._address = address
        self._irq_off, self._irq_on = critical
        self._bus_active = None
        self.target = None
        self.mem = bytearray(MEM_SIZE)
        view = memoryview(self.mem)
        self._mailbox = view[MAILBOX:MAILBOX + MAILBOX_SIZE]
        self._state = view[STATE:STATE + STATE_SIZE]
        self._empty = bytearray(MAILBOX_SIZE)
        for i in range(MAILBOX_SIZE):
            self._empty[i] = _EMPTY_CMD
        self._empty[M_SEQ] = _EMPTY_SEQ
        self._rx = bytearray(MAILBOX_SIZE)
        self._inbox = bytearray(self._empty)  # the last write, taken from the mailbox at its END_WRITE
        self._last = bytearray(self._empty)  # the last frame accepted (retries are ignored)
        self._staged = bytearray(STATE_SIZE)
        self._published = bytearray(STATE_SIZE)
        self._seen_state = bytearray(STATE_SIZE)
        self._frame = bytearray(1 + PAYLOAD_SIZE)
        self._judge_command = core.judge  # the legacy register's checks: returns the reject reason
        self._mailbox[:] = self._empty
        self.ack = 0
        self.verdict = REASON_OK
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
        """END_WRITE (soft IRQ): count the write and take the mailbox it wrote, leaving it empty,
        so the next write lands on an empty mailbox (a short one then fails its framing) and each
        frame judged is one write, however many writes come in one main-loop pass. A frame not
        judged yet is replaced: the newest wins, as in the mailbox before."""
        self.writes = (self.writes + 1) & COUNTER_MASK
        self._inbox[:] = self._mailbox
        self._mailbox[:] = self._empty

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
        self._rx[:] = self._inbox
        self._inbox[:] = self._empty
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
        if overflow or rx[M_SEQ] & _EMPTY_SEQ:
            self.frame_errors = (self.frame_errors + 1) & COUNTER_MASK
            self.verdict = REASON_FRAME
            return
        if _mailbox_crc(rx, self._address) != rx[M_CRC]:
            self.crc_errors = (self.crc_errors + 1) & COUNTER_MASK
            self.verdict = REASON_CRC
            return
        ahead = (rx[M_SEQ] - self.ack) & SEQ_MASK
        if ahead == 0 and rx == self._last:
            self.retries = (self.retries + 1) & COUNTER_MASK  # the host retried a transfer: applied once, verdict unchanged
            return
        if ahead == 0 or ahead >= SEQ_WINDOW:
            self.sequence_errors = (self.sequence_errors + 1) & COUNTER_MASK
            self.verdict = REASON_SEQUENCE
            return
        self.ack = rx[M_SEQ]
        self._last[:] = rx
        self.verdict = self._apply(rx)
        self.applied_writes = self.writes
        if self.verdict == REASON_OK:
            if rx[M_CMD] == CMD_NONE:
                self.polls = (self.polls + 1) & COUNTER_MASK
            else:
                self.applied = (self.applied + 1) & COUNTER_MASK
        else:
            self.rejected = (self.rejected + 1) & COUNTER_MASK

    def _apply(self, rx):
        cmd = rx[M_CMD]
        if cmd == CMD_NONE:
            return REASON_OK
        n = self._core.registers.command_size(cmd)
        if n == NOT_A_COMMAND:
            return REASON_COMMAND
        for i in range(M_PAYLOAD + n, M_PAYLOAD + PAYLOAD_SIZE):
            if rx[i]:
                return REASON_VALUE  # the padding must be zero
        frame = self._frame
        frame[0] = cmd
        for i in range(n):
            frame[1 + i] = rx[M_PAYLOAD + i]
        return FROM_LEGACY[self._judge_command(frame, 1 + n)]

    def _pack(self):
        core = self._core
        out = self._staged
        out[0] = (STATUS_MARKER | (self.verdict << REASON_SHIFT)
                  | (core.flags & STATUS_FLAGS))
        values = core.reply_values
        pos = rescale(values[0], ANGLE_Q - POSITION_Q, POSITION_MAX)
        vel = rescale(values[1], RPM_Q - VELOCITY_Q, VELOCITY_MAX)
        p = S_POSITION - STATE
        out[p] = pos & 0xFF
        out[p + 1] = (pos >> 8) & 0xFF
        out[p + 2] = (pos >> 16) & 0xFF
        v = S_VELOCITY - STATE
        out[v] = vel & 0xFF
        out[v + 1] = VELOCITY_MARKER | ((vel >> 8) & 0x7F)
        out[S_ACK - STATE] = self.ack
        out[S_CRC - STATE] = _state_crc(out, self._address)


def _make_room():
    """Collect garbage now if the heap is nearly full (MicroPython), so that re-creating the I2C
    target and its handler does not trigger a collection while the joint is off the bus."""
    mem_free = getattr(gc, "mem_free", None)
    if mem_free is not None and mem_free() < _ROOM:
        gc.collect()


class ProtocolSwitch:
    """Which map the joint serves. It boots legacy (the original host works unchanged); the
    legacy PROTOCOL register (2) moves it to v2; the v2 PROTOCOL command (1) or `SILENCE_MS`
    without a write from the host moves it back. The switch happens in the main loop, never while
    a transaction is in progress; back to legacy only once the host's next transaction has ended
    (it has read the command's verdict by then). While v2 is served the core runs without
    critical sections (`set_critical(None)`): nothing in an IRQ shares its state then.

    `make_target(mem)` creates the `I2CTarget` (mem None: the legacy IRQ target; else the v2
    memory with `mem_addrsize=0`), `legacy_adapter()` the legacy IRQ path (I2CTargetAdapter)
    before its target exists, attached to it once created, and
    `bus_active_for(target)` the target's activity probe (a callable, True mid-transaction);
    `mem_link` the v2 link's class (None: MemLink).
    """

    def __init__(self, core, address, make_target, legacy_adapter, critical, bus_active_for, mem_link=None):
        self._core = core
        self._mem_link = mem_link or MemLink
        self._address = address
        self._make_target = make_target
        self._legacy_adapter = legacy_adapter
        self._critical = critical
        self._bus_active_for = bus_active_for
        self.protocol = PROTOCOL_LEGACY
        self._request = 0  # a protocol the host asked for, not served yet
        self._request_writes = -1
        self.switches = 0
        self.link = None
        adapter = legacy_adapter()
        _make_room()
        self._join_legacy(adapter)

    def _join_legacy(self, adapter):
        # Nothing allocates between the target's creation and its handler but the handler.
        self.target = self._make_target(None)
        adapter.attach(self.target)
        self.adapter = adapter
        self._bus_active = self._bus_active_for(self.target)

    def service(self):
        """Main loop, after the core's iteration."""
        core = self._core
        request = core.protocol_request
        if request:
            core.protocol_request = 0
            if request != self.protocol:
                self._request = request
                self._request_writes = self.link.applied_writes if self.link is not None else -1
        link = self.link
        # Never while a transaction is in progress: re-creating the target cuts it off.
        if (self._request and (link is None or link.writes != self._request_writes)
                and not self._bus_active()):
            # A v2 joint keeps its map until a transaction after the one that carried the
            # command has ended: the host reads the verdict there, and a legacy write before
            # the switch would only overwrite the mailbox.
            self._switch(self._request)
            link = self.link
        if link is not None:
            link.poll()
            silent = core.clock.ticks_diff(core.clock.ticks_ms(), link.last_write_ms)
            if silent > SILENCE_MS and not self._bus_active():
                core.log.warn("v2 host silent for %d ms: serving the legacy map" % silent)
                self._switch(PROTOCOL_LEGACY)

    def _leave(self):
        if self.link is not None:
            self.link.detach()
            self.link = None
        if self.adapter is not None:
            self.adapter.deinit()
            self.adapter = None
        self.target.deinit()

    def _switch(self, protocol):
        # Allocate while the old target still serves: a garbage collection between leaving the
        # bus and joining it again (tens of ms on the chip) would NAK the host meanwhile.
        link = self._mem_link(self._core, self._address, self._critical) if protocol == PROTOCOL_V2 else None
        adapter = self._legacy_adapter() if link is None else None
        _make_room()
        self._leave()
        if link is not None:
            # No Python IRQ shares the core's state in v2, and an interrupt held off at the end
            # of a write phase shifts the mem-mode transfer (MemLink._swap): no critical sections.
            self._core.set_critical(None)
            self.target = self._make_target(link.mem)
            self._bus_active = self._bus_active_for(self.target)
            link.attach(self.target, self._bus_active)
            self.link = link
        else:
            self._core.set_critical(self._critical)
            self._join_legacy(adapter)
        self.protocol = protocol
        self._request = 0
        self.switches += 1
        self._core.log.info("serving protocol %s" % ("v2" if protocol == PROTOCOL_V2 else "legacy"))

    def deinit(self):
        self._leave()
