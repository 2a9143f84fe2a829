"""CircuitPython `i2ctarget` adapter: the same joint core, polled from the main loop.

CircuitPython has no I2C IRQ callbacks; it stretches the clock while Python answers a request,
which Raspberry Pi 0-3 controllers mishandle (reference/i2c-facts.md sections 3-4). Call `poll()`
from the main loop, right after `JointController.service()`.
"""

from ..spec.protocol import MAX_FRAME, MAX_REPLY


class CircuitPythonTargetAdapter:
    def __init__(self, core, target):
        self._core = core
        self._target = target
        self._frame = bytearray(MAX_FRAME)
        self._reply = bytearray(MAX_REPLY)

    def poll(self):
        """Serve at most one pending request; returns True if there was one."""
        request = self._target.request(timeout=-1)
        if request is None:
            return False
        with request:
            if request.is_read:
                n = self._core.reply_into(self._reply)
                request.write(self._reply[MAX_REPLY - n:])
            else:
                data = request.read()
                n = len(data)
                for i in range(min(n, MAX_FRAME)):
                    self._frame[i] = data[i]
                self._core.on_frame(self._frame, n)
        self._core.host_seen()
        return True
