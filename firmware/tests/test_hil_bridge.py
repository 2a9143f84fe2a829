"""HIL bridge framing and firmware against a fake machine.I2C and a fake serial stream.

Runs under CPython and under the MicroPython unix port (hil_bridge is on both paths).
"""

from hil_bridge import framing as F
from hil_bridge.bridge import VERSION, Bridge
from joint.sim.i2c_target import heap_lock, heap_unlock


class FakeClock:
    def __init__(self):
        self.ms = 0

    def ticks_ms(self):
        return self.ms

    def ticks_diff(self, a, b):
        return a - b


class FakeStream:
    """The USB serial port: bytes the host sent wait in `incoming`; answers collect in `out`
    (preallocated, so writing allocates nothing)."""

    def __init__(self, size=4096):
        self.incoming = bytearray(size)
        self.head = 0
        self.tail = 0
        self.out = bytearray(size)
        self.out_len = 0

    def send(self, data):
        for b in data:
            self.incoming[self.tail] = b
            self.tail += 1

    def readinto(self, buf):
        n = 0
        while n < len(buf) and self.head < self.tail:
            buf[n] = self.incoming[self.head]
            self.head += 1
            n += 1
        return n

    def write(self, buf):
        for i in range(len(buf)):
            self.out[self.out_len] = buf[i]
            self.out_len += 1

    def take(self):
        data = bytes(self.out[:self.out_len])
        self.out_len = 0
        return data


class Memory:
    """An I2C memory device: the first written byte selects a register, the rest is stored there;
    reads continue from the selected register."""

    def __init__(self):
        self.cells = bytearray(range(256))
        self.pointer = 0

    def write(self, data):
        if len(data):
            self.pointer = data[0]
            for b in data[1:]:
                self.cells[self.pointer] = b
                self.pointer = (self.pointer + 1) & 0xFF

    def read_into(self, buf):
        for i in range(len(buf)):
            buf[i] = self.cells[self.pointer]
            self.pointer = (self.pointer + 1) & 0xFF


class FakeI2C:
    """machine.I2C as rp2 behaves: a missing address raises EIO; `fail` makes every call raise."""

    def __init__(self, devices):
        self.devices = devices
        self.calls = []
        self.fail = 0

    def _device(self, addr):
        if self.fail:
            raise OSError(self.fail)
        if addr not in self.devices:
            raise OSError(5)
        return self.devices[addr]

    def writeto(self, addr, buf, stop=True):
        self.calls.append(("writeto", addr, bytes(buf), stop))
        self._device(addr).write(buf)
        return len(buf)

    def readfrom_into(self, addr, buf, stop=True):
        self.calls.append(("readfrom_into", addr, len(buf)))
        self._device(addr).read_into(buf)

    def scan(self):
        if self.fail:
            raise OSError(self.fail)
        return sorted(self.devices)


def frame(kind, seq, payload):
    buf = bytearray(F.MAX_FRAME)
    for i, b in enumerate(payload):
        buf[F.HEADER + i] = b
    return bytes(buf[:F.seal(buf, kind, seq, len(payload))])


def xfer(seq, addr, write, read_len):
    return frame(F.XFER, seq, bytes([addr, read_len]) + bytes(write))


class Rig:
    def __init__(self, devices=None, i2c=True):
        self.clock = FakeClock()
        self.stream = FakeStream()
        self.i2c = FakeI2C({0x50: Memory()} if devices is None else devices) if i2c else None
        self.bridge = Bridge(self.i2c, self.stream, self.clock, 400000)

    def ask(self, data, polls=4):
        """Send bytes, poll the bridge, return the answers as (kind, seq, status, data) tuples."""
        self.stream.send(data)
        for _ in range(polls):
            self.bridge.poll()
        return self.answers()

    def answers(self):
        parser = F.FrameParser()
        found = []
        pos = 0
        out = self.stream.take()
        while True:
            pos = parser.feed(out, pos)
            if not parser.ready:
                break
            p = parser.buf
            found.append((parser.kind, parser.seq, p[F.HEADER], bytes(p[F.HEADER + 1:parser.size - 2])))
            parser.release()
        assert parser.skipped == 0 and parser.crc_errors == 0, "the bridge wrote something unframed"
        return found


# ---- framing ----

def test_crc16_is_ccitt_false():
    assert F.crc16(b"123456789", 0, 9) == 0x29B1
    assert F.crc16(b"", 0, 0) == 0xFFFF


def test_a_sealed_frame_has_the_documented_layout():
    data = frame(F.XFER, 7, b"\x11\x01\x0f")
    assert data[:7] == bytes([0xA5, 3, F.XFER, 7, 0x11, 0x01, 0x0F])
    crc = F.crc16(data, 1, 7)
    assert data[7:] == bytes([crc >> 8, crc & 0xFF])
    assert F.crc16(data, 1, len(data)) == 0, "CRC over the whole frame leaves no remainder"


def _parse_all(data, chunk=1000, quiet_end=False):
    """Frames in data fed in chunks; quiet_end: the stream then goes quiet (see expire())."""
    parser = F.FrameParser()
    found = []

    def collect():
        while parser.ready:
            found.append((parser.kind, parser.seq, bytes(parser.buf[F.HEADER:parser.size - 2])))
            parser.release()

    for start in range(0, len(data), chunk):
        end = min(start + chunk, len(data))
        pos = start
        while pos < end:
            pos = parser.feed(data, pos, end)
            collect()
    while quiet_end and parser.partial:
        parser.expire()
        collect()
    return found, parser


def test_parser_finds_frames_between_garbage_fed_in_any_chunks():
    first, second = frame(F.SCAN, 1, b""), frame(F.XFER, 2, b"\x11\x05\x0f")
    # Stray start bytes: one followed by an impossible length, one by a plausible one.
    data = b"\x00\xa5\xff\x13garbage" + first + b"\xa5\x02" + second + b"\xa5" + second[:4]
    expected = [(F.SCAN, 1, b""), (F.XFER, 2, b"\x11\x05\x0f")]
    for chunk in (1, 3, 7, len(data)):
        found, parser = _parse_all(data, chunk)
        assert found == expected, (chunk, found)
        assert parser.skipped > 0 and parser.partial, "garbage counted; the trailing start is held"


def test_a_bit_flip_anywhere_is_caught_and_the_next_frame_still_found():
    good = frame(F.XFER, 9, b"\x12\x02\x18\x01\x02")
    for bit in range(8 * len(good)):
        broken = bytearray(good)
        broken[bit // 8] ^= 1 << (bit % 8)
        found, parser = _parse_all(bytes(broken) + good, quiet_end=True)
        assert found == [(F.XFER, 9, b"\x12\x02\x18\x01\x02")], bit
        assert parser.crc_errors + parser.bad_lengths + parser.skipped > 0


def test_a_frame_starting_inside_a_truncated_one_is_found():
    good = frame(F.VERSION, 3, b"")
    truncated = frame(F.XFER, 2, bytes(20))[:10]
    found, parser = _parse_all(truncated + good + bytes(30))
    assert found == [(F.VERSION, 3, b"")] and parser.crc_errors == 1


def test_expire_rescans_a_truncated_frame():
    good = frame(F.VERSION, 3, b"")
    parser = F.FrameParser()
    parser.feed(frame(F.XFER, 2, bytes(60))[:10] + good)
    assert not parser.ready and parser.partial, "waits for the long frame's remaining bytes"
    parser.expire()
    assert parser.ready and parser.seq == 3


def test_an_impossible_length_is_skipped():
    found, parser = _parse_all(bytes([0xA5, F.MAX_PAYLOAD + 1]) + frame(F.SCAN, 4, b""))
    assert found == [(F.SCAN, 4, b"")] and parser.bad_lengths == 1


# ---- bridge ----

def test_write_then_read_uses_a_repeated_start():
    rig = Rig()
    assert rig.ask(xfer(1, 0x50, b"\x10", 4)) == [(F.XFER | F.RESPONSE, 1, F.OK, bytes([16, 17, 18, 19]))]
    assert rig.i2c.calls == [("writeto", 0x50, b"\x10", False), ("readfrom_into", 0x50, 4)]


def test_write_only_read_only_and_probe():
    rig = Rig()
    assert rig.ask(xfer(2, 0x50, b"\x20\xaa\xbb", 0)) == [(F.XFER | F.RESPONSE, 2, F.OK, b"")]
    assert rig.i2c.calls[-1] == ("writeto", 0x50, b"\x20\xaa\xbb", True)
    assert rig.ask(frame(F.READ, 3, b"\x50\x01")) == [(F.READ | F.RESPONSE, 3, F.OK, b"\x22")]
    assert rig.i2c.calls[-1] == ("readfrom_into", 0x50, 1)
    assert rig.ask(xfer(4, 0x50, b"", 0)) == [(F.XFER | F.RESPONSE, 4, F.OK, b"")]
    assert rig.i2c.calls[-1] == ("writeto", 0x50, b"", True)


def test_a_missing_address_answers_nack():
    rig = Rig()
    assert rig.ask(xfer(5, 0x51, b"\x0f", 2)) == [(F.XFER | F.RESPONSE, 5, F.NACK, b"")]
    assert rig.ask(xfer(6, 0x51, b"", 0)) == [(F.XFER | F.RESPONSE, 6, F.NACK, b"")]
    assert rig.bridge.statuses[F.NACK] == 2


def test_bus_timeout_and_other_errors():
    rig = Rig()
    rig.i2c.fail = 110  # ETIMEDOUT: a target holding SCL low
    assert rig.ask(xfer(7, 0x50, b"\x0f", 2)) == [(F.XFER | F.RESPONSE, 7, F.TIMEOUT, b"")]
    rig.i2c.fail = 11  # EAGAIN: arbitration lost on some ports
    assert rig.ask(xfer(8, 0x50, b"\x0f", 2)) == [(F.XFER | F.RESPONSE, 8, F.BUS_ERROR, b"")]
    rig.i2c.fail = 0
    assert rig.ask(xfer(9, 0x50, b"\x0f", 1))[0][2] == F.OK


def test_malformed_requests_answer_bad_frame_and_touch_no_bus():
    rig = Rig()
    for seq, request in enumerate((
        frame(0x33, 10, b""),  # unknown kind
        frame(F.XFER, 11, b"\x50"),  # no read length
        frame(F.XFER, 12, bytes([0x50, F.MAX_DATA + 1])),  # read too long
        frame(F.XFER, 13, b"\x80\x01"),  # not a 7-bit address
        frame(F.READ, 14, b"\x50\x00"),  # a read of nothing
        frame(F.READ, 15, b"\x50\x01\x02"),  # a read with write bytes
        frame(F.SCAN, 16, b"\x00"),
        frame(F.VERSION, 17, b"\x00"),
    )):
        answer = rig.ask(request)
        assert answer == [((request[2] | F.RESPONSE) & 0xFF, request[3], F.BAD_FRAME, b"")], (seq, answer)
    assert rig.i2c.calls == []


def test_corrupted_requests_get_no_answer_and_garbage_is_skipped():
    rig = Rig()
    request = bytearray(xfer(20, 0x50, b"\x10", 1))
    request[5] ^= 0x40
    assert rig.ask(request) == []
    assert rig.bridge.parser.crc_errors == 1
    assert rig.ask(b"\x00\x01\xa5\xa5\x99noise" + xfer(21, 0x50, b"\x10", 1)) == [
        (F.XFER | F.RESPONSE, 21, F.OK, b"\x10")]
    assert rig.i2c.calls == [("writeto", 0x50, b"\x10", False), ("readfrom_into", 0x50, 1)]


def test_a_truncated_request_is_dropped_after_a_quiet_spell():
    rig = Rig()
    assert rig.ask(xfer(22, 0x50, bytes(40), 0)[:12]) == []
    rig.stream.send(xfer(23, 0x50, b"\x30", 1))
    rig.bridge.poll()
    assert rig.answers() == [], "its bytes still look like the rest of the long frame"
    rig.clock.ms += 25
    rig.bridge.poll()
    assert rig.answers() == [(F.XFER | F.RESPONSE, 23, F.OK, b"\x30")]


def test_several_requests_in_one_read_are_all_answered_in_order():
    rig = Rig()
    answers = rig.ask(xfer(30, 0x50, b"\x01", 1) + xfer(31, 0x50, b"\x02", 1) + frame(F.VERSION, 32, b""),
                      polls=1)
    assert [(a[1], a[2]) for a in answers] == [(30, F.OK), (31, F.OK), (32, F.OK)]


def test_scan_answers_a_bitmap():
    rig = Rig({0x11: Memory(), 0x14: Memory(), 0x50: Memory()})
    ((kind, seq, status, data),) = rig.ask(frame(F.SCAN, 40, b""))
    assert (kind, seq, status, len(data)) == (F.SCAN | F.RESPONSE, 40, F.OK, F.SCAN_BYTES)
    found = [a for a in range(128) if data[a >> 3] & (1 << (a & 7))]
    assert found == [0x11, 0x14, 0x50]


def test_version_reports_protocol_firmware_and_bus_speed():
    ((_, seq, status, data),) = Rig().ask(frame(F.VERSION, 41, b""))
    assert (seq, status) == (41, F.OK)
    assert tuple(data[:5]) == (F.PROTOCOL,) + VERSION + (F.MAX_DATA,)
    assert int.from_bytes(data[5:9], "little") == 400000


def test_no_i2c_controller_answers_bus_error_but_still_its_version():
    rig = Rig(i2c=False)
    assert rig.ask(xfer(42, 0x50, b"", 0))[0][2] == F.BUS_ERROR
    assert rig.ask(frame(F.SCAN, 43, b""))[0][2] == F.BUS_ERROR
    assert rig.ask(frame(F.VERSION, 44, b""))[0][2] == F.OK


def test_responses_are_never_answered():
    rig = Rig()
    assert rig.ask(frame(F.XFER | F.RESPONSE, 45, b"\x00")) == []


class QuietI2C:
    """An I2C controller double that allocates nothing, to show the bridge itself does not."""

    def writeto(self, addr, buf, stop=True):
        return len(buf)

    def readfrom_into(self, addr, buf, stop=True):
        for i in range(len(buf)):
            buf[i] = i


def test_answering_a_transaction_allocates_nothing_once_warm():
    rig = Rig()
    rig.bridge._i2c = QuietI2C()
    request = xfer(50, 0x11, b"\x18", 5)
    rig.ask(request)  # warm-up: the memoryviews for these lengths are made once
    rig.stream.send(request)
    heap_lock()
    try:
        rig.bridge.poll()
    finally:
        heap_unlock()
    assert rig.answers() == [(F.XFER | F.RESPONSE, 50, F.OK, bytes(range(5)))]


def test_mpremotes_interrupt_between_frames_returns_to_the_repl():
    rig = Rig()
    rig.stream.send(b"\r\x03")
    try:
        rig.bridge.poll()
    except KeyboardInterrupt:
        pass
    else:
        assert False, "CR + Ctrl-C between frames must end the bridge loop"


def test_cr_and_ctrl_c_inside_a_frame_are_data():
    rig = Rig()
    assert rig.ask(xfer(7, 0x50, b"\x0d\x03", 1)) == [(F.XFER | F.RESPONSE, 7, F.OK, b"\x0e")]
    assert rig.i2c.calls[0] == ("writeto", 0x50, b"\x0d\x03", False)
