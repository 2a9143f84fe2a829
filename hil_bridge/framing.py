"""Serial framing of the HIL bridge, shared by the bridge firmware (MicroPython) and the host.

Every frame, in both directions:

    0      1    2     3    4 .. 4+LEN-1   4+LEN  5+LEN
    SOF    LEN  KIND  SEQ  payload        CRC-16 (big-endian)

* SOF is 0xA5. LEN is the payload length (0..MAX_PAYLOAD); a larger LEN cannot start a frame.
* KIND is the request kind; a response has the request's kind with bit 7 set and the request's SEQ.
* CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection) over LEN, KIND, SEQ and the
  payload: 16 bits keep the chance that garbage passes as a frame at 1/65536 (an 8-bit CRC would
  accept one in 256 random starts), it detects every error burst up to 16 bits, and a 256-entry
  table makes it a few operations per byte on the MCU.

Requests (host -> bridge) and their payloads:

    XFER     addr, read_len, write bytes...   write phase (0 bytes: address probe), then a
                                              repeated START and read_len bytes if read_len > 0
    READ     addr, read_len                   read phase only
    SCAN     (none)
    VERSION  (none)

Responses (bridge -> host): status, then the data: the bytes read (XFER, READ), a 16-byte bitmap
of acknowledging addresses, bit a%8 of byte a//8 (SCAN), or framing protocol version, firmware
major, minor, patch, MAX_DATA and the I2C clock in Hz as u32 little-endian (VERSION).

`FrameParser` is fed bytes as they arrive and finds frames in any stream: it skips garbage,
rejects a bad LEN or CRC by dropping only the start byte and rescanning what it holds, so the next
valid frame is found even when it began inside a broken one. It preallocates its buffer.
"""

from array import array

try:
    from micropython import const
except ImportError:
    def const(value):
        return value

PROTOCOL = const(1)
SOF = const(0xA5)
MAX_DATA = const(128)  # bytes written or read by one transaction
MAX_PAYLOAD = const(130)  # addr, read_len, MAX_DATA write bytes
HEADER = const(4)  # SOF, LEN, KIND, SEQ
OVERHEAD = const(6)  # header and CRC
MAX_FRAME = const(136)  # OVERHEAD + MAX_PAYLOAD

XFER = const(0x01)
READ = const(0x02)
SCAN = const(0x03)
VERSION = const(0x04)
RESPONSE = const(0x80)  # set in the KIND of every response
KINDS = (XFER, READ, SCAN, VERSION)

OK = const(0)
NACK = const(1)  # the address or a written byte was not acknowledged
TIMEOUT = const(2)  # the bus did not complete in time (a target holding SCL, no pull-ups)
BAD_FRAME = const(3)  # a valid frame the bridge cannot execute (unknown kind, bad lengths)
BUS_ERROR = const(4)  # any other I2C failure (arbitration lost, no I2C controller)
STATUS_NAMES = ("ok", "NACK", "timeout", "bad frame", "bus error")

SCAN_BYTES = const(16)  # bitmap of addresses 0..127
VERSION_BYTES = const(9)


def _make_table():
    table = array("H", bytes(512))
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
        table[i] = crc & 0xFFFF
    return table


_TABLE = _make_table()


def crc16(buf, start, end, crc=0xFFFF):
    """CRC-16/CCITT-FALSE of buf[start:end], continuing from `crc`."""
    table = _TABLE
    for i in range(start, end):
        crc = ((crc << 8) & 0xFF00) ^ table[(crc >> 8) ^ buf[i]]
    return crc


def seal(buf, kind, seq, n):
    """Complete the frame whose n payload bytes already sit at buf[HEADER:]; returns its length."""
    buf[0] = SOF
    buf[1] = n
    buf[2] = kind
    buf[3] = seq
    end = HEADER + n
    crc = crc16(buf, 1, end)
    buf[end] = crc >> 8
    buf[end + 1] = crc & 0xFF
    return end + 2


def status_name(status):
    return STATUS_NAMES[status] if 0 <= status < len(STATUS_NAMES) else "status %d" % status


class FrameParser:
    """Finds frames in a byte stream. Feed it with `feed()`; while `ready`, the frame is at
    `buf[0:size]` (kind, seq, payload via the properties); `release()` moves on to the next one.

    Counters: `frames` good frames, `skipped` garbage bytes, and the frames it abandoned:
    `bad_lengths` (an impossible LEN), `crc_errors` (a wrong CRC), `truncated` (see `expire`).
    """

    def __init__(self):
        self.buf = bytearray(MAX_FRAME)
        self.n = 0  # bytes held
        self.size = 0  # length of the ready frame
        self.ready = False
        self.frames = 0
        self.skipped = 0
        self.bad_lengths = 0
        self.crc_errors = 0
        self.truncated = 0

    @property
    def kind(self):
        return self.buf[2]

    @property
    def seq(self):
        return self.buf[3]

    @property
    def payload_len(self):
        return self.buf[1]

    @property
    def partial(self):
        """True while it holds the start of a frame that has not completed."""
        return self.n > 0 and not self.ready

    def feed(self, data, pos=0, end=-1):
        """Take bytes from data[pos:end] until a frame is ready; returns the position reached."""
        if end < 0:
            end = len(data)
        buf = self.buf
        while pos < end and not self.ready:
            byte = data[pos]
            pos += 1
            if self.n == 0 and byte != SOF:
                self.skipped += 1
                continue
            buf[self.n] = byte
            self.n += 1
            self._settle()
        return pos

    def release(self):
        """Done with the ready frame: look for the next one in the bytes already held."""
        if self.ready:
            self.ready = False
            self._drop(self.size)
            self._settle()

    def expire(self):
        """The stream went quiet in the middle of a frame: it was truncated; rescan past its start."""
        if self.partial:
            self.truncated += 1
            self.skipped += 1
            self._drop(1)
            self._settle()

    def reset(self):
        """Forget everything held (e.g. before a new request: older bytes cannot answer it)."""
        self.n = 0
        self.ready = False

    def _drop(self, k):
        buf = self.buf
        n = self.n - k
        for i in range(n):
            buf[i] = buf[k + i]
        self.n = n

    def _settle(self):
        """Bring the held bytes to a state: empty, a partial frame, or a ready frame."""
        buf = self.buf
        while self.n:
            if buf[0] != SOF:
                k = 1
                while k < self.n and buf[k] != SOF:
                    k += 1
                self.skipped += k
                self._drop(k)
                continue
            if self.n < 2:
                return
            if buf[1] > MAX_PAYLOAD:
                self.bad_lengths += 1
                self.skipped += 1
                self._drop(1)
                continue
            size = OVERHEAD + buf[1]
            if self.n < size:
                return
            if crc16(buf, 1, size - 2) == (buf[size - 2] << 8 | buf[size - 1]):
                self.size = size
                self.ready = True
                self.frames += 1
                return
            self.crc_errors += 1
            self.skipped += 1
            self._drop(1)
