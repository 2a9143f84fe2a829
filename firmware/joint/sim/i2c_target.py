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

`mem=buffer` is the memory mode, as extmod/machine_i2c_target.c runs it in C on every port: a write
first sets the address pointer from its first `mem_addrsize/8` bytes (MSB first, modulo the buffer
length; with 0 every write starts at offset 0), then stores bytes at the
pointer, wrapping at the end; a read serves bytes from the pointer, wrapping, one per request,
and the hardware's extra request (prefetch / RX_DONE) moves the pointer once more (an N-byte read
leaves it at start + N + 1). END_WRITE is not raised for a write that only set the address.
`memaddr` is the last address selected. A user handler for WRITE_REQ/READ_REQ runs before the
built-in copy. Soft handlers (`hard=False`) run as the scheduler runs them, with the heap
unlocked: before the main thread's next step, i.e. before `on_wire` if the main loop runs in the
middle of the transaction (an END_WRITE at the repeated START is seen during the read), else
after the transaction. `on_wire`, if set, is called between bytes (tests use it to run the
joint's main loop in the middle of a transaction); `active` is what the peripheral's activity
status bit shows. After `deinit()` the target answers no more: the rest of a transaction in
progress reads 0xFF (SDA released) and its written bytes are lost.
"""

try:
    from micropython import heap_lock, heap_unlock
except ImportError:
    def heap_lock():
        pass

    def heap_unlock():
        pass

from ..links.i2c_target import (
    IRQ_ADDR_MATCH_READ, IRQ_ADDR_MATCH_WRITE, IRQ_END_READ, IRQ_END_WRITE, IRQ_READ_REQ,
    IRQ_WRITE_REQ,
)

_FIFO = 16
PORTS = ("rp2", "stm32")

# extmod's target state machine.
_IDLE = 0
_ADDR_MATCH_READ = 1
_ADDR_MATCH_WRITE = 2
_MEM_ADDR_SELECT = 3
_READING = 4
_WRITING = 5


class FakeI2CTarget:
    IRQ_ADDR_MATCH_READ = IRQ_ADDR_MATCH_READ
    IRQ_ADDR_MATCH_WRITE = IRQ_ADDR_MATCH_WRITE
    IRQ_READ_REQ = IRQ_READ_REQ
    IRQ_WRITE_REQ = IRQ_WRITE_REQ
    IRQ_END_READ = IRQ_END_READ
    IRQ_END_WRITE = IRQ_END_WRITE

    def __init__(self, addr, port="rp2", mem=None, mem_addrsize=8):
        if port not in PORTS:
            raise ValueError("port must be one of %s" % (PORTS,))
        if mem is not None and mem_addrsize not in (0, 8, 16, 24, 32):
            raise ValueError("mem_addrsize must be 0, 8, 16, 24 or 32")
        self.addr = addr
        self.port = port
        self._fifo_depth = _FIFO if port == "rp2" else 1
        self._handler = None
        self._trigger = 0
        self._hard = False
        self._flags = 0
        self._soft_pending = 0
        self._mem = mem
        self._mem_addrsize = mem_addrsize // 8 if mem is not None else 0
        self._state = _IDLE
        self._mem_addr = 0
        self._mem_addr_last = 0
        self._mem_addr_count = 0
        self.active = False
        self.on_wire = None
        self._live = True
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
            self._hard = hard
        return self

    @property
    def memaddr(self):
        return self._mem_addr_last

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

    @property
    def serves_memory(self):
        """Memory mode: the port serves every byte in C, with no handler holding SCL."""
        return self._mem is not None

    def deinit(self):
        self._handler = None
        self._live = False

    # ---- the controller side, used by the simulated bus ----

    @property
    def handler_installed(self):
        return self._handler is not None

    def _fire(self, event):
        """handle_event: True if a handler took the event."""
        handler = self._handler
        if handler is None or not self._trigger & event:
            return False
        if self._mem is not None and not self._hard:
            self._soft_pending |= event
            return True
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
            return True
        heap_unlock()
        return True

    def _run_soft(self):
        events = self._soft_pending
        self._soft_pending = 0
        for event in (IRQ_END_WRITE, IRQ_END_READ):
            if events & event and self._handler is not None:
                self._flags = event
                self._handler(self)

    def transfer(self, data, read_len):
        """One controller transaction: write `data` (None: no write phase), then read `read_len`."""
        if self._mem is not None:
            return self._mem_transfer(data, read_len)
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

    # ---- memory mode: extmod/machine_i2c_target.c's state machine, driven as the rp2 port does ----

    def _wire(self):
        if self.on_wire is not None:
            self._run_soft()
            self.on_wire()

    def _reset_helper(self):
        if self._state == _READING:
            self._fire(IRQ_END_READ)
        elif self._state in (_ADDR_MATCH_WRITE, _WRITING):
            self._fire(IRQ_END_WRITE)
        self._state = _IDLE

    def _addr_match(self, read):
        self._reset_helper()
        if read:
            self._fire(IRQ_ADDR_MATCH_READ)
            self._state = _ADDR_MATCH_READ
        else:
            self._fire(IRQ_ADDR_MATCH_WRITE)
            self._state = _ADDR_MATCH_WRITE

    def _write_request(self):
        if not self._live:
            self._rx_pos = self._rx_len
            return
        self._fire(IRQ_WRITE_REQ)  # a user handler may take bytes first (readinto)
        mem = self._mem
        while self._rx_pos < self._rx_len:
            val = self._rx[self._rx_pos]
            self._rx_pos += 1
            if self._state == _ADDR_MATCH_WRITE:
                self._state = _MEM_ADDR_SELECT
                self._mem_addr = 0
                self._mem_addr_count = self._mem_addrsize
            if self._state == _MEM_ADDR_SELECT and self._mem_addr_count > 0:
                self._mem_addr = (self._mem_addr << 8) | val
                self._mem_addr_count -= 1
                if self._mem_addr_count == 0:
                    self._mem_addr %= len(mem)
                    self._mem_addr_last = self._mem_addr
            else:
                if self._state == _MEM_ADDR_SELECT:
                    self._state = _WRITING
                mem[self._mem_addr] = val
                self._mem_addr += 1
                if self._mem_addr >= len(mem):
                    self._mem_addr = 0
            self._wire()

    def _read_request(self):
        if not self._live:
            return 0xFF
        self._fire(IRQ_READ_REQ)
        mem = self._mem
        if self._state == _MEM_ADDR_SELECT:  # only part of a multi-byte address arrived
            self._mem_addr %= len(mem)
            self._mem_addr_last = self._mem_addr
        self._state = _READING
        val = mem[self._mem_addr]
        self._mem_addr += 1
        if self._mem_addr >= len(mem):
            self._mem_addr = 0
        self._wire()
        return val

    def _mem_transfer(self, data, read_len):
        self.active = True
        self._state = _IDLE
        if data is not None:
            self._addr_match(False)  # at the first byte (rp2 RX_FULL), or at STOP for 0 bytes
            i = 0
            while i < len(data):
                self._rx_len = 0
                self._rx_pos = 0
                while i < len(data) and self._rx_len < 4:  # the mem logic drains 4 bytes per call
                    self._rx[self._rx_len] = data[i]
                    self._rx_len += 1
                    i += 1
                self._write_request()
            self._reset_helper()  # the repeated START (or STOP) closes the write phase
        out = bytearray(read_len)
        if read_len > 0:
            self._addr_match(True)
            for i in range(read_len + 1):  # N bytes, plus the prefetch (RX_DONE on rp2)
                byte = self._read_request()
                if i < read_len:
                    out[i] = byte
            self._reset_helper()
        self.active = False
        self._run_soft()
        return bytes(out)
