"""Linux /dev/i2c-N through smbus2, with the original driver's exact wire transactions.

A register read is `i2c_rdwr(write([reg]), read(n))` and a command `i2c_rdwr(write([reg, payload...]),
read(1))`: one I2C_RDWR ioctl each, repeated START between the messages, one STOP, exactly what
lgpio's I2C block read and zip commands put on the wire for the original host.
"""

from __future__ import annotations

from typing import Any, Callable

from smbus2 import SMBus, i2c_msg

from .base import Bus


class SMBusBus(Bus):
    scheme = "smbus"

    def __init__(self, bus: int | str = 1, *, smbus_factory: Callable[[Any], Any] = SMBus, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.bus_id = bus
        try:
            self._smbus = smbus_factory(bus)
        except (FileNotFoundError, PermissionError) as exc:
            path = bus if isinstance(bus, str) else f"/dev/i2c-{bus}"
            hint = ("enable I2C (raspi-config, or dtparam=i2c_arm=on)" if isinstance(exc, FileNotFoundError)
                    else "add your user to the i2c group")
            raise OSError(exc.errno, f"cannot open {path}: {exc.strerror}; {hint}") from exc

    def describe(self) -> str:
        return f"smbus:{self.bus_id}"

    def _transfer_once(self, addr: int, write: bytes | None, read_len: int) -> bytes:
        messages = []
        if write is not None:
            messages.append(i2c_msg.write(addr, write))
        reply = i2c_msg.read(addr, read_len) if read_len else None
        if reply is not None:
            messages.append(reply)
        self._smbus.i2c_rdwr(*messages)
        return bytes(reply) if reply is not None else b""

    def _probe(self, addr: int) -> bool:
        try:
            self._smbus.i2c_rdwr(i2c_msg.write(addr, b""))
        except OSError:
            return False
        return True

    def close(self) -> None:
        if not self._closed:
            self._smbus.close()
        super().close()
