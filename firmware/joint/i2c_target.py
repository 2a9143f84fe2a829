"""The I2C IRQ path: `machine.I2CTarget` hard-IRQ events to the joint core, allocation-free.

Event handling (see reference/i2c-facts.md section 1.4). Only the four events that carry work are
asked for: each event the handler takes costs a Python call inside the interrupt (tens of
microseconds on an RP2040), and on rp2 a read's first byte waits, SCL held low, for every call
still pending from the write before it.

* WRITE_REQ drains received bytes (one per event on most ports, a FIFO batch on rp2) straight into
  the preallocated frame buffer (past MAX_FRAME, an overlong frame's bytes are only counted);
  END_WRITE (at STOP or at the repeated START) takes what is left in the FIFO and hands the frame
  to the core, which validates and queues it, then starts the next frame. A write with no read is
  a complete command; a 0-byte write (address probe) ends with END_WRITE alone.
* The read's first READ_REQ asks the core for the reply (payload + flags, packed in advance by the
  main loop, the flags written in as of now); a read with no register written first repeats the
  last selected register. Each READ_REQ then feeds the reply: `write()` gets the rest of it at
  once, and the port takes what it can (one byte on most ports, up to the TX FIFO on rp2). The
  hardware asks for one byte past the end (prefetch, or rp2's RX_DONE), which gets a pad byte.
  END_READ closes the transaction.
"""

from .emitters import micropython, ptr8

from .irq import FTAB_WLEN, REGISTER_SPACE
from .protocol import MAX_FRAME

try:
    from micropython import const
except ImportError:
    def const(value):
        return value

IRQ_ADDR_MATCH_READ = const(1)
IRQ_ADDR_MATCH_WRITE = const(2)
IRQ_READ_REQ = const(4)
IRQ_WRITE_REQ = const(8)
IRQ_END_READ = const(16)
IRQ_END_WRITE = const(32)
IRQ_ALL = const(63)
TRIGGER = const(60)  # READ_REQ | WRITE_REQ | END_READ | END_WRITE
_CHUNK = const(16)  # rp2 RX FIFO depth
COUNTER_MASK = const(0x1FFFFFFF)  # irq.COUNTER_MASK (viper needs this module's constants)
_MAX_FRAME = const(5)
_WLEN = const(64)  # where irq.py's frame table keeps each register's command frame length
_REGISTERS = const(64)  # every register address is below this
_FRAME_OPEN = const(-2)  # _reply_pos: no read in progress, a frame kept open
if _MAX_FRAME != MAX_FRAME or _WLEN != FTAB_WLEN or _REGISTERS != REGISTER_SPACE:
    raise ImportError("i2c_target.py: constants differ from protocol.py / irq.py")


def _never():
    return False


class I2CTargetAdapter:
    """Connects a `machine.I2CTarget` (or the simulator's fake) to a JointController.

    `whole_reply_writes=False` hands `write()` one byte at a time, for ports whose `write()`
    reports 1 even when it queued more (alif).

    `bus_active()` is true while a transaction addressed to the target is in progress (the RP2040's
    activity bit, app.bus_activity_probe). The rp2 driver reads its interrupt status once per
    interrupt: when a STOP is serviced late, after the next transaction's START and first byte, it
    ends that transaction's write (END_WRITE) after its first bytes. A command frame that ends
    short while the bus is still active is therefore kept open: the rest of it follows, and a read
    (repeated START) closes it as it is.
    """

    def __init__(self, core, target, whole_reply_writes=True, bus_active=None):
        self._core = core
        self._target = target
        self._whole = whole_reply_writes
        self._frame = bytearray(MAX_FRAME + _CHUNK)
        view = memoryview(self._frame)
        # Where the next received bytes go, by frame length so far (an overlong frame's extra
        # bytes land past MAX_FRAME): made now because slicing in the IRQ would allocate. Each
        # has room for a whole RX FIFO.
        self._rx_at = [view[i:] for i in range(MAX_FRAME + 1)]
        self._frame_len = 0
        self._one = bytearray(1)
        self._pad = bytearray(1)
        self._wire = core._reply_wire
        self._reply_len = 0
        self._reply_pos = -1  # -1: no read in progress
        # Bound methods made once: looking them up in the IRQ would walk the core's mixins.
        self._on_frame = core.on_frame
        self._ftab = core._ftab
        self._bus_active = bus_active or _never
        self._wires = core._wires
        self._ticks_us = core._ticks_us
        self._handler = self._irq
        # The irq object first: a host already polling at boot fires the handler the moment it is set.
        self._events = target.irq()
        target.irq(self._handler, trigger=TRIGGER, hard=True)

    def deinit(self):
        self._target.irq(None, trigger=0, hard=True)

    @micropython.viper
    def _irq(self, target):
        # The events in the order of their urgency: a READ_REQ holds SCL until it is answered.
        event = int(self._events.flags())  # one event per call
        if event == IRQ_READ_REQ:
            pos = int(self._reply_pos)
            if pos < 0:  # the read's first request: the selected reply, its flags as of now
                if pos == _FRAME_OPEN:  # a frame kept open (see the class docstring) ends here
                    length = int(self._frame_len)
                    self._frame_len = 0
                    self._on_frame(self._frame, length)
                core = self._core
                wire = core._reply_wire
                n = int(len(wire))
                ptr8(wire)[n - 1] = int(core.flags) | int(core._reply_err)
                if self._whole:
                    sent = int(target.write(wire))
                else:
                    ptr8(self._one)[0] = ptr8(wire)[0]
                    sent = int(target.write(self._one))
                # SCL runs again once the port has the first byte: the bookkeeping comes after.
                self._reply_pos = sent
                self._wire = wire
                self._reply_len = n
                return
            if pos < int(self._reply_len):  # a port that took less: the rest a byte at a time
                ptr8(self._one)[0] = ptr8(self._wire)[pos]
                self._reply_pos = pos + int(target.write(self._one))
            else:
                self._reply_pos = pos
                target.write(self._pad)
            return
        if event == IRQ_WRITE_REQ:
            length = int(self._frame_len)
            at = self._rx_at[length if length < _MAX_FRAME else _MAX_FRAME]
            self._frame_len = length + int(target.readinto(at))
            return
        core = self._core
        if event == IRQ_END_WRITE:
            # END_WRITE drains too: rp2 handles a repeated START before the RX data that came with
            # it, so the last bytes of a command can still be in the FIFO (chip/README.md).
            length = int(self._frame_len)
            length += int(target.readinto(self._rx_at[length if length < _MAX_FRAME else _MAX_FRAME]))
            addr = ptr8(self._frame)[0]
            if length == 1 and addr < _REGISTERS:  # selected for reading: on_frame's first case
                selection = self._wires[addr]
                if selection:
                    core._reply_wire = selection
                    core._reply_err = 0
                    self._frame_len = 0
                    return  # the read that follows ends the transaction (END_READ feeds the deadman)
            if length and length < _MAX_FRAME and addr < _REGISTERS:  # (no frame is longer)
                if length < ptr8(self._ftab)[_WLEN + addr]:
                    if self._bus_active():
                        self._frame_len = length  # cut short by the driver: the rest follows
                        self._reply_pos = _FRAME_OPEN
                        return
            self._frame_len = 0  # (a _FRAME_OPEN left in _reply_pos only closes an empty frame)
            self._on_frame(self._frame, length)
        else:  # END_READ
            self._reply_pos = -1
        core.host_us = self._ticks_us()  # host_seen(), inlined: the deadman counts from here
        core.transactions = (int(core.transactions) + 1) & COUNTER_MASK
