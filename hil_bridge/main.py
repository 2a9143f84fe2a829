"""Board entry of the HIL bridge (any MicroPython board with USB serial, e.g. a Raspberry Pi Pico).

Deploy: copy the `hil_bridge` folder to the board and this file as `/main.py`. An optional
`/bridge_config.json` overrides the defaults below, e.g. {"scl": 17, "sda": 16, "freq": 100000}.
The I2C controller answers on USB serial (stdin/stdout), which becomes binary: a plain Ctrl-C byte
no longer interrupts (frames may contain 0x03), but mpremote's CR + Ctrl-C between frames still
returns to the REPL, so `mpremote` can update the bridge as usual.
"""

import json
import select
import sys
import time

import machine
import micropython

from hil_bridge.bridge import Bridge

DEFAULTS = {"id": 0, "scl": 5, "sda": 4, "freq": 400000, "timeout_us": 50000}
CONFIG_FILE = "bridge_config.json"


class UsbSerial:
    """stdin/stdout as a non-blocking binary stream (stdin.readinto would wait for a full buffer)."""

    def __init__(self):
        self._poll = select.poll()
        self._poll.register(sys.stdin, select.POLLIN)
        self._in = sys.stdin.buffer
        self._out = sys.stdout.buffer
        self._one = bytearray(1)
        self._ready()  # ipoll allocates the tuple it reuses on its first call

    def readinto(self, buf):
        n = 0
        while n < len(buf) and self._ready():
            if not self._in.readinto(self._one):
                break  # end of input: readable, but nothing to read
            buf[n] = self._one[0]
            n += 1
            if self._one[0] == 0x03:
                break  # a possible REPL escape: what follows (mpremote's Ctrl-A) is the REPL's
        return n

    def _ready(self):
        for _ in self._poll.ipoll(0):  # ipoll reuses one result tuple: poll() builds a list
            return True
        return False

    def write(self, buf):
        self._out.write(buf)


def settings():
    """DEFAULTS with the integer values of the config file applied; unknown keys are ignored."""
    values = dict(DEFAULTS)
    try:
        with open(CONFIG_FILE) as f:
            loaded = json.load(f)
    except (OSError, ValueError):
        return values
    if type(loaded) is dict:
        for key in DEFAULTS:
            if type(loaded.get(key)) is int:
                values[key] = loaded[key]
    return values


def open_i2c(cfg):
    """The I2C controller, or None if these pins or this speed cannot work (answers BUS_ERROR)."""
    try:
        return machine.I2C(cfg["id"], scl=machine.Pin(cfg["scl"]), sda=machine.Pin(cfg["sda"]),
                           freq=cfg["freq"], timeout=cfg["timeout_us"])
    except (ValueError, OSError, TypeError):
        return None


def run():
    micropython.kbd_intr(-1)  # binary frames may contain 0x03
    try:
        cfg = settings()
        bridge = Bridge(open_i2c(cfg), UsbSerial(), time, cfg["freq"])
        while True:
            if not bridge.poll():
                machine.idle()
    finally:
        micropython.kbd_intr(3)


run()
