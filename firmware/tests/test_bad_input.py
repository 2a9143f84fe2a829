"""Bad input never escapes the IRQ path, always sets ERROR in the reply and never moves the motor."""

import struct

from joint.spec import protocol as P
from harness import Rig, Xorshift

NON_FINITE = (float("nan"), float("inf"), float("-inf"))


def _assert_rejected(rig, data, why):
    rig.motor.calls = []
    flags = rig.xfer(data, 1)[0]
    rig.run_ms(1)
    assert flags & P.FLAG_ERROR, "%s: %r not flagged" % (why, data)
    assert rig.motor.calls == [], "%s: %r commanded the motor: %r" % (why, data, rig.motor.calls)
    rig.assert_handler_alive()


def _enabled_rig():
    rig = Rig()
    rig.command("SETUP", 20, 20, 0, 0)
    rig.run_ms(1)
    return rig


def test_wrong_payload_lengths_for_every_register():
    rig = _enabled_rig()
    for reg in P.REGISTERS:
        lengths = [n for n in (1, 2, 3, 4, 5, 6, 9) if n != reg.wsize]
        if not reg.readable:
            lengths.append(0)
        for n in lengths:
            _assert_rejected(rig, bytes([reg.addr]) + bytes(n), "%s with %d bytes" % (reg.name, n))


def test_unknown_and_unsupported_registers():
    rig = _enabled_rig()
    for addr in range(256):
        reg = P.BY_ADDR[addr]
        if reg is None or not reg.supported:
            for payload in (b"", b"\x00", b"\x01\x02\x03\x04"):
                _assert_rejected(rig, bytes([addr]) + payload, "register 0x%02x" % addr)
                assert rig.read("LASTERROR")[0][1] == addr


def test_non_finite_and_out_of_range_values_for_every_field():
    rig = _enabled_rig()
    for reg in P.REGISTERS:
        if not reg.writable:
            continue
        good = []
        for f in reg.write:
            good.append(f.hi if f.kind == P.U8 else (f.hi if f.kind == P.F32 else 0))
        for i, f in enumerate(reg.write):
            bad = []
            if f.kind == P.F32:
                bad = list(NON_FINITE) + [f.hi * 1.01 + 1, -(f.hi * 1.01 + 1)]
                if f.lo > 0:
                    bad.append(f.lo / 2)
            elif f.kind == P.U8:
                bad = [v for v in (f.lo - 1, f.hi + 1) if 0 <= v <= 255]
            for value in bad:
                values = list(good)
                values[i] = value
                payload = struct.pack(reg.wfmt, *values)
                _assert_rejected(rig, bytes([reg.addr]) + payload, "%s.%s=%r" % (reg.name, f.name, value))


def test_garbage_byte_streams():
    rig = _enabled_rig()
    rng = Xorshift(1234)
    for _ in range(600):
        data = rng.bytes(rng.below(12))
        rig.motor.calls = []
        reply = rig.xfer(data if rng.below(5) else None, rng.below(8))
        rig.run_ms(1)
        rig.assert_handler_alive()
        reg = P.BY_ADDR[data[0]] if data else None
        valid = reg is not None and (len(data) == 1 and reg.readable
                                     or reg.check_write(data, 1, len(data) - 1) == P.REJECT_NONE)
        if reply and reply[-1] & P.FLAG_ERROR and data:
            assert not valid or rig.read("LASTERROR")[0][0] in (P.REJECT_BUSY, P.REJECT_QUEUE_FULL)
        if not valid:
            assert rig.motor.calls == [], (data, rig.motor.calls)
        rig.command("STOP", 0)
        rig.command("SETUP", 20, 20, 0, 0)
        rig.run_ms(600)


def test_error_flag_only_marks_the_rejected_frame():
    rig = _enabled_rig()
    assert rig.xfer(bytes([P.SETCURRENT, 200]), 1)[0] & P.FLAG_ERROR
    assert not rig.command("SETCURRENT", 30) & P.FLAG_ERROR
    assert rig.read("PING")[1] == 0x04


def test_angles_beyond_what_the_joint_carries_are_errors_not_clamped_moves():
    rig = _enabled_rig()
    for name in ("MOVEANGLE", "MOVETOANGLE"):
        for value in (262144.0, -262144.5, 1e6, -1e6):
            _assert_rejected(rig, bytes([P.register(name).addr]) + struct.pack("<f", value), "%s %g" % (name, value))
            assert rig.read("LASTERROR")[0][0] == P.REJECT_VALUE
