"""The HIL bridge: framed requests from a serial stream, executed on an I2C controller.

Hardware is injected, so the same code runs on the board, in the tests and in the simulator server:

* `i2c`: a `machine.I2C` (writeto, readfrom_into, scan), or None when the controller failed to
  start (transactions then answer BUS_ERROR, VERSION still answers);
* `stream`: non-blocking bytes; `readinto(buf)` returns how many bytes it read (0 or None when
  none wait), `write(buf)` sends;
* `clock`: `ticks_ms`/`ticks_diff` (the `time` module on the board).

`poll()` does a bounded amount of work and never waits, so the caller owns the loop.
"""

from . import framing as F
from .framing import const

VERSION = (1, 0, 0)
_RX_CHUNK = const(64)
_QUIET_MS = const(20)  # a partial frame followed by this much silence was truncated
_RESULT = const(5)  # F.HEADER + status: where read data starts in a response
_WDATA = const(6)  # F.HEADER + addr + read_len: where write data starts in a request

# errno -> status. MicroPython's values equal Linux's: EIO 5, ENXIO 6, ENODEV 19, ETIMEDOUT 110,
# EREMOTEIO 121. rp2 reports every NACK as EIO, software I2C an address NACK as ENODEV.
_NACK_ERRNOS = (5, 6, 19, 121)
_TIMEOUT_ERRNOS = (110, 116)


def status_of(exc):
    """The response status for an OSError raised by a machine.I2C call."""
    code = exc.args[0] if exc.args else 0
    if code in _NACK_ERRNOS:
        return F.NACK
    if code in _TIMEOUT_ERRNOS:
        return F.TIMEOUT
    return F.BUS_ERROR


class _Views:
    """memoryviews of buf[start:start + n], made once per length (slicing in the loop allocates)."""

    def __init__(self, buf, start, longest):
        self._mv = memoryview(buf)
        self._start = start
        self._cache = [None] * (longest + 1)

    def get(self, n):
        view = self._cache[n]
        if view is None:
            view = self._mv[self._start:self._start + n]
            self._cache[n] = view
        return view


class Bridge:
    """Serves bridge requests; counters: `requests`, `answered` by status, parser's error counts."""

    def __init__(self, i2c, stream, clock, freq=0, repl_escape=True):
        self._i2c = i2c
        self._repl_escape = repl_escape
        self._stream = stream
        self._clock = clock
        self._freq = freq
        self.parser = F.FrameParser()
        self._rx = bytearray(_RX_CHUNK)
        self._tx = bytearray(F.MAX_FRAME)
        self._writes = _Views(self.parser.buf, _WDATA, F.MAX_DATA)
        self._reads = _Views(self._tx, _RESULT, F.MAX_DATA)
        self._frames = _Views(self._tx, 0, F.MAX_FRAME)
        self._last_rx_ms = clock.ticks_ms()
        self.requests = 0
        self.statuses = [0] * len(F.STATUS_NAMES)
        self.replays = 0
        # The last request answered (SEQ, KIND, CRC) and its answer's size: a request seen again
        # is a host retry after a lost answer, so the answer is sent again, not the I2C work redone.
        self._last_seq = -1
        self._last_kind = -1
        self._last_crc = -1
        self._last_size = 0

    def poll(self):
        """Read what the stream holds (up to one chunk) and answer every complete request."""
        n = self._stream.readinto(self._rx) or 0
        parser = self.parser
        if n and self._repl_escape and not parser.partial and self._interrupt_requested(n):
            raise KeyboardInterrupt
        now = self._clock.ticks_ms()
        if n:
            self._last_rx_ms = now
        elif parser.partial and self._clock.ticks_diff(now, self._last_rx_ms) > _QUIET_MS:
            parser.expire()
        pos = 0
        answered = 0
        while True:
            pos = parser.feed(self._rx, pos, n)
            if not parser.ready:
                return answered
            self._answer()
            parser.release()
            answered += 1

    def _interrupt_requested(self, n):
        """mpremote's interrupt, CR then Ctrl-C, between frames: hand the board back to the REPL.

        Ctrl-C itself is off (frames may carry 0x03), so this keeps the bridge board updatable.
        """
        rx = self._rx
        for i in range(1, n):
            if rx[i - 1] == F.SOF:
                return False
            if rx[i] == 0x03 and rx[i - 1] == 0x0D:
                return True
        return False

    def _answer(self):
        parser = self.parser
        req = parser.buf
        kind = parser.kind
        n = parser.payload_len
        tx = self._tx
        length = 0
        if kind & F.RESPONSE:
            return  # another bridge's answer (or an echo): answering it could start a loop
        crc = (req[parser.size - 2] << 8) | req[parser.size - 1]
        if parser.seq == self._last_seq and kind == self._last_kind and crc == self._last_crc:
            self.replays += 1
            self._stream.write(self._frames.get(self._last_size))
            return
        if kind == F.XFER or kind == F.READ:
            rlen = req[5] if n >= 2 else 0
            if n < 2 or req[4] > 0x7F or rlen > F.MAX_DATA or kind == F.READ and (n != 2 or rlen == 0):
                status = F.BAD_FRAME
            else:
                status = self._transaction(kind == F.XFER, req[4], n - 2, rlen)
                if status == F.OK:
                    length = rlen
        elif kind == F.SCAN and n == 0:
            status = self._scan()
            if status == F.OK:
                length = F.SCAN_BYTES
        elif kind == F.VERSION and n == 0:
            status = F.OK
            length = self._version()
        else:
            status = F.BAD_FRAME
        self.requests += 1
        self.statuses[status] += 1
        tx[F.HEADER] = status
        size = F.seal(tx, kind | F.RESPONSE, parser.seq, 1 + length)
        self._last_seq, self._last_kind, self._last_crc, self._last_size = parser.seq, kind, crc, size
        self._stream.write(self._frames.get(size))

    def _transaction(self, write_phase, addr, wlen, rlen):
        i2c = self._i2c
        if i2c is None:
            return F.BUS_ERROR
        try:
            if write_phase:
                # Before a read: no STOP, so the read follows with a repeated START.
                if i2c.writeto(addr, self._writes.get(wlen), rlen == 0) < wlen:
                    return F.NACK
            if rlen:
                i2c.readfrom_into(addr, self._reads.get(rlen))
        except OSError as exc:
            return status_of(exc)
        return F.OK

    def _scan(self):
        """Probe 0x08..0x77 one by one: a stuck bus answers TIMEOUT at the first address that
        times out, instead of after a timeout for every address."""
        if self._i2c is None:
            return F.BUS_ERROR
        tx = self._tx
        for i in range(F.SCAN_BYTES):
            tx[_RESULT + i] = 0
        probe = self._writes.get(0)
        for addr in range(0x08, 0x78):
            try:
                self._i2c.writeto(addr, probe)
            except OSError as exc:
                status = status_of(exc)
                if status == F.NACK:
                    continue
                return status
            tx[_RESULT + (addr >> 3)] |= 1 << (addr & 7)
        return F.OK

    def _version(self):
        tx = self._tx
        tx[_RESULT] = F.PROTOCOL
        tx[_RESULT + 1] = VERSION[0]
        tx[_RESULT + 2] = VERSION[1]
        tx[_RESULT + 3] = VERSION[2]
        tx[_RESULT + 4] = F.MAX_DATA
        freq = self._freq
        for i in range(4):
            tx[_RESULT + 5 + i] = (freq >> (8 * i)) & 0xFF
        return F.VERSION_BYTES
