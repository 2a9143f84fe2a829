"""The Blinka transport with a stand-in busio.I2C: USB adapters report a NACK as RuntimeError."""

from __future__ import annotations

import pytest

from bioscara.bus.blinka import BlinkaBus
from bioscara.errors import CommError


class MCP2221Like:
    """busio.I2C as Blinka's MCP2221 driver behaves: only 0x11 answers; a NACK is a RuntimeError."""

    def __init__(self) -> None:
        self.locked = False

    def try_lock(self) -> bool:
        self.locked = True
        return True

    def unlock(self) -> None:
        self.locked = False

    def deinit(self) -> None:
        pass

    def writeto(self, addr: int, buf: bytes) -> None:
        if addr != 0x11:
            raise RuntimeError("I2C slave address was NACK'd")

    def writeto_then_readfrom(self, addr: int, out: bytes, into: bytearray) -> None:
        self.writeto(addr, out)
        into[:] = bytes(len(into))


def test_nacks_become_comm_errors_after_retries_and_scan_works() -> None:
    bus = BlinkaBus(i2c=MCP2221Like())
    assert bus.transfer(0x11, b"\x0f", 2) == b"\x00\x00"
    with pytest.raises(CommError, match="0x12.*NACK.*after 3 attempts"):
        bus.transfer(0x12, b"\x0f", 2)
    assert bus.stats.link(0x12).failed_attempts == 3
    assert bus.scan() == [0x11]
    bus.close()
