"""`make bench-chip` measures every register of the map (bench/chip_bus.py register_cases): every
register is a case, and each case takes the path it names, accepted or rejected, on the simulated
joint as the bench runs it on the chip (restored with STOP and SETUP before each, its setup and
per-repeat frames sent, a few ms apart)."""

from __future__ import annotations

import chip_bus
from harness import Rig
from joint.spec import protocol as P

GAP_MS = round(chip_bus.GAP_US / 1000)


def test_every_register_of_the_map_is_a_case() -> None:
    names = [case.name for case in chip_bus.register_cases()]
    assert len(names) == len(set(names))
    assert {reg.name for reg in P.REGISTERS} <= set(names)
    assert {"read." + reg.name for reg in P.REGISTERS if reg.writable and reg.readable} <= set(names)
    assert sum(name.startswith("reject.") for name in names) >= 8


def test_every_case_is_accepted_or_rejected_as_it_says() -> None:
    rig = Rig()
    restore = [chip_bus.legacy_transaction("STOP"), chip_bus.legacy_transaction("SETUP")]

    def send(write: bytes, read_len: int) -> bytes:
        reply = bytes(rig.xfer(write, read_len))
        rig.run_ms(GAP_MS)
        return reply

    for case in chip_bus.register_cases():
        for write, read_len in restore + list(case.setup):
            send(write, read_len)
        for _ in range(2):
            for write, read_len in case.before:
                send(write, read_len)
            reply = send(case.write, case.read_len)
            flags = reply[0 if case.rejected else case.read_len - 1]
            assert bool(flags & P.FLAG_ERROR) == case.rejected, (case.name, reply.hex())
