"""A stand-in for `machine.I2CTarget` that a simulated controller drives, event for event.

`transfer(data, read_len)` produces exactly the hard-IRQ event sequence a real port produces for
one controller transaction (reference/i2c-facts.md section 1.4):

* write phase (also for a 0-byte address probe): ADDR_MATCH_WRITE, WRITE_REQ while received bytes
  wait in the RX FIFO, END_WRITE (at STOP, or at the repeated START when a read follows);
* read phase: ADDR_MATCH_READ, READ_REQ whenever the controller needs a byte and the TX FIFO is
  empty, plus one more READ_REQ after the last byte (the hardware prefetch, or rp2's RX_DONE),
  END_READ.

`port="rp2"`: `write()` queues up to the 16-byte TX FIFO and `readinto()` drains the RX FIFO.
`port="stm32"`: both move one byte per call, as on stm32/mimxrt/samd/zephyr.

Like a hard IRQ, every handler call runs with the heap locked (MicroPython) and an exception
removes the handler. The FIFOs are preallocated so `readinto`/`write` never allocate either.
"""

try:
    from micropython import heap_lock, heap_unlock
except ImportError:
    def heap_lock():
        pass

    def heap_unlock():
        pass

from ..i2c_target import (
    IRQ_ADDR_MATCH_READ, IRQ_ADDR_MATCH_WRITE, IRQ_END_READ, IRQ_END_WRITE, IRQ_READ_REQ,
    IRQ_WRITE_REQ,
)

_FIFO = 16
PORTS = ("rp2", "stm32")


class FakeI2CTarget:
    IRQ_ADDR_MATCH_READ = IRQ_ADDR_MATCH_READ
    IRQ_ADDR_MATCH_WRITE = IRQ_ADDR_MATCH_WRITE
    IRQ_READ_REQ = IRQ_READ_REQ
    IRQ_WRITE_REQ = IRQ_WRITE_REQ
    IRQ_END_READ = IRQ_END_READ
    IRQ_END_WRITE = IRQ_END_WRITE

    def __init__(self, addr, port="rp2"):
        if port not in PORTS:
            raise ValueError("port must be one of %s" % (PORTS,))
        self.addr = addr
        self.port = port
        self._fifo_depth = _FIFO if port == "rp2" else 1
        self._handler = None
        self._trigger = 0
        self._flags = 0
        self._rx = bytearray(_FIFO)
        self._rx_len = 0
        self._rx_pos = 0
        self._tx = bytearray(_FIFO)
        self._tx_len = 0
        self._tx_pos = 0
        self.handler_failures = 0
        self.last_failure = None

    # ---- the machine.I2CTarget side, used by the firmware ----

    def irq(self, handler=None, trigger=None, hard=False):
        if trigger is not None or handler is not None:
            self._handler = handler
            self._trigger = trigger or 0
        return self

    def flags(self):
        return self._flags

    def readinto(self, buf):
        n = 0
        limit = min(len(buf), self._fifo_depth)
        while n < limit and self._rx_pos < self._rx_len:
            buf[n] = self._rx[self._rx_pos]
            self._rx_pos += 1
            n += 1
        return n

    def write(self, buf):
        n = 0
        while n < len(buf) and self._tx_len - self._tx_pos < self._fifo_depth:
            self._tx[self._tx_len % _FIFO] = buf[n]
            self._tx_len += 1
            n += 1
        return n

    def deinit(self):
        self._handler = None

    # ---- the controller side, used by the simulated bus ----

    @property
    def handler_installed(self):
        return self._handler is not None

    def _fire(self, event):
        handler = self._handler
        if handler is None or not self._trigger & event:
            return
        self._flags = event
        heap_lock()
        try:
            handler(self)
        except Exception as exc:  # a real port prints this and removes the handler
            heap_unlock()
            self.handler_failures += 1
            self.last_failure = exc
            self._handler = None
            print("Uncaught exception in IRQ callback handler")
            return
        heap_unlock()

    def transfer(self, data, read_len):
        """One controller transaction: write `data` (None: no write phase), then read `read_len`."""
        if data is not None:
            self._fire(IRQ_ADDR_MATCH_WRITE)
            i = 0
            while i < len(data):
                self._rx_len = 0
                self._rx_pos = 0
                while i < len(data) and self._rx_len < self._fifo_depth:
                    self._rx[self._rx_len] = data[i]
                    self._rx_len += 1
                    i += 1
                while self._rx_pos < self._rx_len:
                    before = self._rx_pos
                    self._fire(IRQ_WRITE_REQ)
                    if self._rx_pos == before:
                        self._rx_pos = self._rx_len  # nobody read: the port discards the bytes
            self._fire(IRQ_END_WRITE)
        out = bytearray(read_len)
        if read_len > 0:
            self._tx_len = self._tx_pos = 0
            self._fire(IRQ_ADDR_MATCH_READ)
            # One-byte ports prefetch a byte past the end; rp2 instead reports RX_DONE as READ_REQ.
            fetches = read_len if self.port == "rp2" else read_len + 1
            for i in range(fetches):
                if self._tx_pos == self._tx_len:
                    self._fire(IRQ_READ_REQ)
                if self._tx_pos < self._tx_len:
                    byte = self._tx[self._tx_pos % _FIFO]
                    self._tx_pos += 1
                else:
                    byte = 0  # the port's default when the handler supplies nothing
                if i < read_len:
                    out[i] = byte
            if self.port == "rp2":
                self._fire(IRQ_READ_REQ)
            self._fire(IRQ_END_READ)
            self._tx_len = self._tx_pos = 0  # leftovers are flushed at the next transaction
        return bytes(out)
