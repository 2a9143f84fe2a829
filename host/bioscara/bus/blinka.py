"""Any Adafruit Blinka board's `busio.I2C` (Raspberry Pi, or USB adapters such as MCP2221 and FT232H).

Blinka is imported only when this transport is chosen (`blinka:`), so hosts without it are fine.
"""

from __future__ import annotations

import errno
import time
from typing import Any

from .base import Bus

LOCK_TIMEOUT_S = 5.0


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
        deadline = time.monotonic() + LOCK_TIMEOUT_S
        while not self._i2c.try_lock():
            if time.monotonic() > deadline:
                raise OSError(errno.EBUSY, f"the Blinka I2C bus stayed locked for {LOCK_TIMEOUT_S:g} s")
            time.sleep(0.001)

    def _transfer_once(self, addr: int, write: bytes | None, read_len: int) -> bytes:
        reply = bytearray(read_len)
        try:
            if write is not None and read_len:
                self._i2c.writeto_then_readfrom(addr, write, reply)
            elif write is not None:
                self._i2c.writeto(addr, write)
            elif read_len:
                self._i2c.readfrom_into(addr, reply)
        except RuntimeError as exc:  # USB adapters (MCP2221) report a NACK as RuntimeError
            raise OSError(errno.EREMOTEIO, str(exc)) from exc
        return bytes(reply)

    def _probe(self, addr: int) -> bool:
        try:
            self._i2c.writeto(addr, b"")
        except (OSError, RuntimeError):
            return False
        return True

    def close(self) -> None:
        if not self._closed:
            self._i2c.unlock()
            self._i2c.deinit()
        super().close()
