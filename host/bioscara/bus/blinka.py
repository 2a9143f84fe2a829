"""Any Adafruit Blinka board's `busio.I2C` (Raspberry Pi, or USB adapters such as MCP2221 and FT232H).

Blinka is imported only when this transport is chosen (`blinka:`), so hosts without it are fine.
"""

from __future__ import annotations

from typing import Any

from .base import Bus


class BlinkaBus(Bus):
    scheme = "blinka"

    def __init__(self, i2c: Any = None, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        if i2c is None:
            try:
                import board
                import busio
            except (ImportError, NotImplementedError, RuntimeError) as exc:
                raise OSError(f"Adafruit Blinka is not available here ({exc}); "
                              "install it with `pip install bioscara[blinka]` and set BLINKA_* for USB adapters") from exc
            i2c = busio.I2C(board.SCL, board.SDA, frequency=self.speed_hz)
        self._i2c = i2c
        while not self._i2c.try_lock():
            pass

    def _transfer_once(self, addr: int, write: bytes | None, read_len: int) -> bytes:
        reply = bytearray(read_len)
        if write is not None and read_len:
            self._i2c.writeto_then_readfrom(addr, write, reply)
        elif write is not None:
            self._i2c.writeto(addr, write)
        elif read_len:
            self._i2c.readfrom_into(addr, reply)
        return bytes(reply)

    def _probe(self, addr: int) -> bool:
        try:
            self._i2c.writeto(addr, b"")
        except OSError:
            return False
        return True

    def close(self) -> None:
        if not self._closed:
            self._i2c.unlock()
            self._i2c.deinit()
        super().close()
