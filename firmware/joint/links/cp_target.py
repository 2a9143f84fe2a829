"""CircuitPython `i2ctarget` link: the same joint core, polled from the main loop.

CircuitPython has no I2C IRQ callbacks and no memory-mode target: `i2ctarget.I2CTarget` holds SCL
low on a read (and on a full RX FIFO) until Python answers `request()`, so the host waits for the
main loop (reference/i2c-facts.md sections 3-4: Raspberry Pi 0-3 controllers mishandle that).
The loop calls `poll()` between its steps, and the longest step sets how long SCL is held.
Each request is an object CircuitPython allocates, a write's bytes another and each look at the
RX FIFO's registers a third; nothing else allocates. What runs between the end of the host's
write and the reply holds SCL: the write's bytes go to the core as read (its judge only reads
them) and the reply straight from its wire buffer, no copy either way (each one a bytecode loop
here: about 0.1 ms).
"""

from ..micro import const

WRITE_WAIT_POLLS = const(16)  # checks (~40 us each) for the end of a write: 5 bytes at 100 kHz
READ_WAIT_POLLS = const(8)  # request() calls (~30 us each on the chip) waiting for a write's read


class CircuitPythonTargetAdapter:
    def __init__(self, core, target, fifo):
        self._core = core
        self._target = target
        self._fifo = fifo  # the bus's RX FIFO level and end of write (cpy/hardware.TargetFifo)
        self.served = 0  # requests answered (wraps like the core's counters)

    def poll(self):
        """Serve a pending request, and after a write the read that follows it: one transaction
        (MicroPython's IRQ path counts one per STOP or repeated START); returns True if there
        was one."""
        request = self._target.request()
        if request is None:
            return False
        served = 1
        if not self._serve(request):
            # The host reads its reply right after the write (repeated START): wait for the
            # read here, a few address-byte times, instead of leaving SCL held until the next poll.
            for _ in range(READ_WAIT_POLLS):
                request = self._target.request()
                if request is not None:
                    self._serve(request)
                    served = 2
                    break
        # Once the transaction's reply is out, not between its write and read (SCL held there).
        self._core.host_seen()
        self.served = (self.served + served) & 0x3FFFFFFF
        return True

    def _serve(self, request):
        """Answer `request` (closed on return); returns whether it was a read."""
        with request:
            is_read = request.is_read
            if is_read:
                request.write(self._core.reply_wire())
            else:
                # The bytes the write left, once it has ended: read() without a count costs
                # about 1 ms more (cpy/hardware.TargetFifo), and the host waits, SCL held.
                fifo = self._fifo
                for _ in range(WRITE_WAIT_POLLS):
                    if fifo.write_ended():
                        data = request.read(fifo.rx_level())
                        break
                else:
                    data = request.read()  # still being written: read() waits for its end
                self._core.on_frame(data, len(data))
        return is_read

    def deinit(self):
        self._target.deinit()
