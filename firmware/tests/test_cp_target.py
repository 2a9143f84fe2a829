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

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def read(self, n=-1, ack=True):
        return bytearray(self._data)

    def write(self, buf):
        self.written += bytes(buf)
        return len(buf)


class FakeCPTarget:
    def __init__(self):
        self.pending = []

    def request(self, timeout=-1):
        return self.pending.pop(0) if self.pending else None


def _transact(adapter, target, data, read):
    requests = [FakeRequest(False, data)] + ([FakeRequest(True)] if read else [])
    target.pending.extend(requests)
    while adapter.poll():
        pass
    return requests[-1].written if read else None


def test_register_read_and_command_through_circuitpython():
    rig = Rig()
    target = FakeCPTarget()
    adapter = CircuitPythonTargetAdapter(rig.core, target)
    rig.motor.angle = 33.0
    rig.run_ms(1)
    assert _transact(adapter, target, bytes([P.ANGLEMOVED]), True) == struct.pack("<f", 33.0) + b"\x0c"
    assert _transact(adapter, target, bytes([P.SETUP, 20, 20, 0, 0]), True) == b"\x04"
    assert _transact(adapter, target, bytes([P.SETCURRENT, 222]), True)[0] & P.FLAG_ERROR
    assert not adapter.poll(), "nothing pending"
