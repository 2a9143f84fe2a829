"""Protocol v2 on the joint: the memory map of protocol_v2.py served by `I2CTarget(mem=...)`, and
the switch between the legacy register map and v2 (`MemLink` is in memlink.py, loaded by the
first switch to v2).

`MemLink` runs in the main loop only; the peripheral's C code serves the bus byte by byte from
`mem` with no Python while SCL is held. Each `poll()`:

1. packs the next state block into a staging buffer (integers only: the position and velocity are
   the legacy ANGLEMOVED / GETENCODERRPM reply caches, converted from their float32 bits);
2. swaps, in one short critical section entered only while no transaction is in progress (the
   peripheral's activity bit, checked before and inside it: interrupts held off across the end
   of a write phase shift the rp2 transfer): takes the mailbox out and marks it empty, notes
   whether the host wrote past it into the state block, and publishes the staged block. A read
   therefore always sees one whole block, and the mailbox is never taken half-written;
3. judges the frame it took: framing, CRC, sequence number, then the legacy register's own checks
   through the core (`on_frame`), exactly as a legacy write of that register would be judged. The
   verdict and the new `ack` go out with the next swap, in the same poll.

Allocation-free once constructed (tests run it with the heap locked under MicroPython).
"""

import gc

try:
    from micropython import const
except ImportError:
    def const(value):
        return value

# protocol_v2's PROTOCOL_LEGACY, PROTOCOL_V2 and SILENCE_MS (test_v2 checks): the switch runs
# without the v2 spec, which memlink.py loads with the first switch to v2.
PROTOCOL_LEGACY = const(1)
PROTOCOL_V2 = const(2)
SILENCE_MS = const(2000)
_ROOM = const(16384)  # bytes free before a protocol switch (its allocations take about 1 KB)


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
    memory with `mem_addrsize=0`), `legacy_adapter(target)` the legacy IRQ path on it, and
    `bus_active_for(target)` the target's activity probe (a callable, True mid-transaction).
    """

    def __init__(self, core, address, make_target, legacy_adapter, critical, bus_active_for):
        self._core = core
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
        self.target = make_target(None)
        self._bus_active = bus_active_for(self.target)
        self.adapter = legacy_adapter(self.target)

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
        link = None
        if protocol == PROTOCOL_V2:
            from .memlink import MemLink  # the first switch to v2 loads it (a few ms, still on the bus)
            link = MemLink(self._core, self._address, self._critical)
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
            self.target = self._make_target(None)
            self._bus_active = self._bus_active_for(self.target)
            self.adapter = self._legacy_adapter(self.target)
        self.protocol = protocol
        self._request = 0
        self.switches += 1
        self._core.log.info("serving protocol %s" % ("v2" if protocol == PROTOCOL_V2 else "legacy"))

    def deinit(self):
        self._leave()
