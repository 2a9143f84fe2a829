"""Protocol v2 on the stm32 port: its I2CTarget (mem= mode) serves the state block from the C
interrupt with no Python, and nothing tells a transaction is in progress, so the S32 publishes its
state block by I2C1's SR2 (RM0368 18.6.7).

TRA, not BUSY: TRA is set with a read's address match, before the first byte goes out (SCL is held
until the interrupt serves it), and cleared by the STOP; BUSY covers every transaction on the bus
(other joints', this joint's write phase). A swap deferred to the next main-loop pass (about 1 ms
on the S32, as long as the host's sync period) locked onto the start of the host's next
transaction, which a deferred pass, shorter, reached again: every ack came two frames late and
`V2Link.sync` never ended. `S32MemLink` waits a read out instead (a state block's read: 8 bytes and
the NACK, 0.2 ms at 400 kHz), which pushes the next pass away from it.
"""

from ..links.memmap_v2 import MemLink
from ..micro import const

_I2C1_SR2 = const(0x40005418)
_I2C_BLOCK = const(0x400)  # I2C2 and I2C3 follow I2C1 at this stride
_SR2_TRA = const(0x4)
_READ_WAIT_US = const(1000)  # longer than a state block's read at 100 kHz (0.8 ms)


def read_in_progress(mem32, bus):
    """A callable true while the host reads from this joint on I2C `bus` (SR2's TRA). Reading SR2
    alone clears no flag (ADDR clears on an SR1 then an SR2 read, in the interrupt)."""
    sr2 = _I2C1_SR2 + (bus - 1) * _I2C_BLOCK

    def reading():
        return mem32[sr2] & _SR2_TRA
    return reading


class S32MemLink(MemLink):
    """MemLink whose swap, with interrupts on, waits for a read in progress to end (up to
    _READ_WAIT_US; then deferred as MemLink defers it)."""

    def _swap(self):
        clock = self._core.clock
        start = clock.ticks_us()
        while self._bus_active() and clock.ticks_diff(clock.ticks_us(), start) < _READ_WAIT_US:
            pass
        return MemLink._swap(self)
