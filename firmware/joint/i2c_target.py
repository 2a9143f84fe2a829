"""The I2C IRQ path: `machine.I2CTarget` hard-IRQ events to the joint core, allocation-free.

Event handling (see reference/i2c-facts.md section 1.4):

* ADDR_MATCH_WRITE starts a frame; WRITE_REQ drains received bytes (one per event on most ports,
  a FIFO batch on rp2) into a preallocated frame buffer; END_WRITE (at STOP or at the repeated
  START) takes what is left in the FIFO and hands the frame to the core, which validates and
  queues it. A write with no read is a complete command.
* ADDR_MATCH_READ asks the core for the reply (payload + flags, packed in advance by the main loop);
  a read with no register written first repeats the last selected register. READ_REQ feeds the
  reply: `write()` gets the rest of the reply at once, and the port takes what it can (one byte on
  most ports, up to the TX FIFO on rp2). The hardware asks for one byte past the end (prefetch),
  which gets a pad byte. END_READ closes the transaction.
"""

from .emitters import micropython

from .irq import COUNTER_MASK
from .protocol import MAX_FRAME, MAX_REPLY

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
_CHUNK = const(16)  # rp2 RX FIFO depth


class I2CTargetAdapter:
    """Connects a `machine.I2CTarget` (or the simulator's fake) to a JointController.

    `whole_reply_writes=False` hands `write()` one byte at a time, for ports whose `write()`
    reports 1 even when it queued more (alif).
    """

    def __init__(self, core, target, whole_reply_writes=True):
        self._core = core
        self._target = target
        self._whole = whole_reply_writes
        self._frame = bytearray(MAX_FRAME)
        self._frame_len = 0
        self._chunk = bytearray(_CHUNK)
        self._reply = bytearray(MAX_REPLY)
        view = memoryview(self._reply)
        # Every suffix of the reply buffer, made now because slicing in the IRQ would allocate.
        self._tails = [view[i:] for i in range(MAX_REPLY)]
        self._one = bytearray(1)
        self._pad = bytearray(1)
        self._reply_len = 0
        self._reply_pos = 0
        # Bound methods made once: looking them up in the IRQ would walk the core's mixins.
        self._on_frame = core.on_frame
        self._reply_into = core.reply_into
        self._ticks_us = core._ticks_us
        self._handler = self._irq
        self._events = target.irq(self._handler, trigger=IRQ_ALL, hard=True)  # the irq object

    def deinit(self):
        self._target.irq(None, trigger=0, hard=True)

    @micropython.native
    def _irq(self, target):
        events = self._events.flags()
        if events & IRQ_ADDR_MATCH_WRITE:
            self._frame_len = 0
        # END_WRITE drains too: rp2 handles a repeated START before the RX data that came with it,
        # so the last bytes of a command can still be in the FIFO (chip/README.md).
        if events & (IRQ_WRITE_REQ | IRQ_END_WRITE):
            chunk = self._chunk
            frame = self._frame
            length = self._frame_len
            n = target.readinto(chunk)
            for i in range(n):
                if length < MAX_FRAME:
                    frame[length] = chunk[i]
                length += 1
            self._frame_len = length
        if events & IRQ_END_WRITE:
            self._on_frame(self._frame, self._frame_len)
            self._frame_len = 0
            core = self._core
            core.host_us = self._ticks_us()  # host_seen(), inlined: the deadman counts from here
            core.transactions = (core.transactions + 1) & COUNTER_MASK
        if events & IRQ_ADDR_MATCH_READ:
            self._reply_len = self._reply_into(self._reply)
            self._reply_pos = 0
        if events & IRQ_READ_REQ:
            pos = self._reply_pos
            if pos < self._reply_len:
                index = MAX_REPLY - self._reply_len + pos
                if self._whole:
                    self._reply_pos = pos + target.write(self._tails[index])
                else:
                    self._one[0] = self._reply[index]
                    self._reply_pos = pos + target.write(self._one)
            else:
                target.write(self._pad)
        if events & IRQ_END_READ:
            core = self._core
            core.host_us = self._ticks_us()
            core.transactions = (core.transactions + 1) & COUNTER_MASK
