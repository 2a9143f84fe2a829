"""A joint on the Pico backend with allocation-free fakes, to count what `service()` allocates.

The fakes on the 1 kHz path (PIO state machine, AS5600 bus) never allocate, so every byte counted
is the firmware's own. The rotor follows the acknowledged pulses exactly (integer usteps); the
TMC2209's UART fake is the test module's (it allocates, but the UART is used only by commands and
boot, never by `service()` in steady state). `bytes_per_service(n)` is meaningful under
MicroPython only (CPython boxes every int): it returns None there.
"""

import gc
import sys

from joint.config import schema as config
from joint.spec import protocol as P
from joint.core.controller import JointController
from joint.links.i2c_target import I2CTargetAdapter
from joint.console.log import Logger
from joint.pico.as5600 import AS5600, RAW_ANGLE, STATUS, CONF
from joint.pico.motor import PicoStepper
from joint.pico.stepgen import StepGenerator, burst_pulses
from joint.pico.tmc2209 import TMC2209
from joint.sim.clock import VirtualClock
from joint.sim.i2c_target import FakeI2CTarget
from pico_fakes import FakeTMCBus

MICROPYTHON = sys.implementation.name == "micropython"
_RING = 8


class RotorSM:
    """rp2.StateMachine whose bursts complete at once and turn the rotor (no allocation)."""

    def __init__(self):
        self._words = [0] * _RING
        self._in = 0
        self._out = 0
        self.rotor = 0  # usteps
        self.blocked = False

    def put(self, word):
        self._words[self._in % _RING] = word
        self._in += 1
        if not self.blocked:
            self.rotor += burst_pulses(word)

    def rx_fifo(self):
        return self._in - self._out

    def get(self):
        word = self._words[self._out % _RING]
        self._out += 1
        return word


class RotorEncoderBus:
    """machine.I2C with an AS5600 reading the rotor (12.5 usteps a count, no allocation)."""

    def __init__(self, sm):
        self._sm = sm
        self.offset = 1000
        self._conf = bytearray(2)
        self._pointer = -1

    def readfrom_mem_into(self, addr, reg, buf):
        self._pointer = reg
        self.readfrom_into(addr, buf)
        if reg != RAW_ANGLE:
            self._pointer = -1  # advanced past the register: a pointer-less read must set it first

    def readfrom_into(self, addr, buf):
        reg = self._pointer
        if reg == RAW_ANGLE:
            raw = (self._sm.rotor * 2 // 25 + self.offset) & 0xFFF
            buf[0] = raw >> 8
            buf[1] = raw & 0xFF
        elif reg == STATUS:
            buf[0] = 0x20
        elif reg == CONF:
            buf[0] = self._conf[0]
            buf[1] = self._conf[1]

    def writeto_mem(self, addr, reg, buf):
        if reg == CONF:
            self._conf[0] = buf[0]
            self._conf[1] = buf[1]


class PicoJoint:
    """JointController + I2CTargetAdapter + PicoStepper on the fakes above, booted (`cfg`: a
    parsed config, e.g. a shipped configs/Jn.json; default: the original's constants)."""

    def __init__(self, joint="J1", cfg=None):
        self.clock = VirtualClock()
        self.sm = RotorSM()
        self.uart = FakeTMCBus()
        self.motor = PicoStepper(TMC2209(self.uart), AS5600(RotorEncoderBus(self.sm)),
                                 StepGenerator(self.sm), None, self.clock)
        self.cfg = cfg or config.default(joint)
        self.lines = []
        self.core = JointController(self.motor, self.clock, self.cfg,
                                    Logger(joint, write=self.lines.append))
        self.target = FakeI2CTarget(self.cfg.address)
        self.adapter = I2CTargetAdapter(self.core)
        self.adapter.attach(self.target)
        self.tick(30000, until_ready=True)
        assert self.core.ready and not self.core.disabled, self.lines

    def tick(self, n=1, until_ready=False, poll_every=0):
        """n service() calls 1 ms apart; with `poll_every`, the host's reads every that many ms."""
        core = self.core
        for i in range(n):
            self.clock.advance(1000)
            if poll_every and i % poll_every == 0:
                self.host_poll()
            core.service()
            if until_ready and core.ready:
                return

    def command(self, name, *values):
        """Send a command as the host does; returns the reply's flags."""
        reg = P.register(name)
        return self.target.transfer(bytes([reg.addr]) + reg.encode(*values), 1)[0]

    def host_poll(self):
        """The original host's cycle reads (ANGLEMOVED, GETENCODERRPM), feeding the deadman."""
        self.target.transfer(bytes([P.ANGLEMOVED]), 5)
        self.target.transfer(bytes([P.GETENCODERRPM]), 5)

    def bytes_per_service(self, n, poll_every=0):
        """Heap bytes allocated by n service() calls, 1 ms apart (None under CPython).

        With `poll_every`, the host's reads arrive every that many ms (outside the count)."""
        if not MICROPYTHON:
            return None
        core = self.core
        clock = self.clock
        total = 0
        gc.collect()
        for i in range(n):
            clock.advance(1000)
            if poll_every and i % poll_every == 0:
                self.host_poll()
            gc.collect()
            before = gc.mem_alloc()
            core.service()
            total += gc.mem_alloc() - before
        return total / n
