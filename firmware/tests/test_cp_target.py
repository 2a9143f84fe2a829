"""The CircuitPython i2ctarget adapter drives the same core as the IRQ path."""

import struct

from joint.spec import protocol as P
from joint.links.cp_target import CircuitPythonTargetAdapter
from harness import Rig


class FakeRequest:
    def __init__(self, is_read, data=b""):
        self.is_read = is_read
        self._data = data
        self.written = b""
        self.counts = []  # read()'s n, call by call

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def read(self, n=-1, ack=True):
        self.counts.append(n)
        return bytearray(self._data if n < 0 else self._data[:n])

    def write(self, buf):
        self.written += bytes(buf)
        return len(buf)


class FakeCPTarget:
    def __init__(self):
        self.pending = []

    def request(self, timeout=-1):
        return self.pending.pop(0) if self.pending else None


class FakeFifo:
    """The RX FIFO of the target's I2C block: `ended` says whether the host's write has ended."""

    def __init__(self, target, ended=True):
        self.target = target
        self.ended = ended
        self.current = None  # the write request being served

    def write_ended(self):
        return self.ended

    def rx_level(self):
        return len(self.current._data)


def _transact(adapter, target, data, read, fifo=None):
    requests = [FakeRequest(False, data)] + ([FakeRequest(True)] if read else [])
    if fifo is not None:
        fifo.current = requests[0]
    target.pending.extend(requests)
    while adapter.poll():
        pass
    return requests[-1].written if read else None


def test_register_read_and_command_through_circuitpython():
    rig = Rig()
    target = FakeCPTarget()
    adapter = CircuitPythonTargetAdapter(rig.core, target, FakeFifo(target))
    rig.motor.angle = 33.0
    rig.run_ms(1)
    adapter._fifo.current = None
    assert _transact(adapter, target, bytes([P.ANGLEMOVED]), True, adapter._fifo) == struct.pack("<f", 33.0) + b"\x0c"
    assert _transact(adapter, target, bytes([P.SETUP, 20, 20, 0, 0]), True, adapter._fifo) == b"\x04"
    assert _transact(adapter, target, bytes([P.SETCURRENT, 222]), True, adapter._fifo)[0] & P.FLAG_ERROR
    assert not adapter.poll(), "nothing pending"


def test_a_write_is_read_by_its_count_once_it_has_ended():
    """The write's bytes are read with the count the RX FIFO holds once the write has ended
    (i2ctarget's read() without a count costs about 1 ms more); a write that has not ended
    within the wait is read without a count, and served the same."""
    for ended in (True, False):
        rig = Rig()
        target = FakeCPTarget()
        fifo = FakeFifo(target, ended)
        adapter = CircuitPythonTargetAdapter(rig.core, target, fifo)
        write = FakeRequest(False, bytes([P.SETUP, 20, 20, 0, 0]))
        read = FakeRequest(True)
        fifo.current = write
        target.pending.extend([write, read])
        while adapter.poll():
            pass
        assert read.written == b"\x04", ended
        assert write.counts == ([5] if ended else [-1])


def test_a_transaction_is_one_for_the_deadman_and_two_requests_for_the_collector():
    """A write, repeated START, read: one transaction counted by the core, as MicroPython's IRQ
    path counts it, and two requests served (cpy/app.py CollectionPlan counts their garbage)."""
    rig = Rig()
    target = FakeCPTarget()
    adapter = CircuitPythonTargetAdapter(rig.core, target, FakeFifo(target))
    before = rig.core.transactions
    _transact(adapter, target, bytes([P.ANGLEMOVED]), True, adapter._fifo)
    assert rig.core.transactions == before + 1
    assert adapter.served == 2
    _transact(adapter, target, bytes([P.SETRPM]) + struct.pack("<f", 1.0), False, adapter._fifo)
    assert rig.core.transactions == before + 2  # a write alone: one too
    assert adapter.served == 3
