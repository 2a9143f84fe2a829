"""A joint serving both protocols (core + ProtocolSwitch) behind fake I2C targets, in virtual time,
and a minimal v2 host for the firmware tests (CPython and the MicroPython unix port)."""

from joint.config import schema as config
from joint.spec import protocol as P, protocol_v2 as V
from joint.core.controller import JointController
from joint.links.i2c_target import I2CTargetAdapter
from joint.console.log import Logger
from joint.sim.clock import VirtualClock
from joint.sim.i2c_target import FakeI2CTarget, heap_lock, heap_unlock
from joint.links.memmap_v2 import ProtocolSwitch

from harness import RecordingMotor


def _off():
    return 0


def _on(state):
    pass


def _activity(target):
    def active():
        return target.active
    return active


class V2Rig:
    """`critical`: the (disable, enable) interrupt pair given to the core and the switch;
    `mem_link`: the v2 link's class (None: MemLink)."""

    def __init__(self, port="rp2", critical=None, mem_link=None):
        self.clock = VirtualClock()
        self.motor = RecordingMotor()
        self.lines = []
        self.cfg = config.default("J1")
        self.address = self.cfg.address
        self.port = port
        self.switch = None
        critical = critical or (_off, _on)
        self.core = JointController(self.motor, self.clock, self.cfg,
                                    Logger("J1", write=self.lines.append), critical)
        self.run_ms(2000)
        assert self.core.ready
        self.switch = ProtocolSwitch(self.core, self.address, self._make_target, self._legacy,
                                     critical, _activity, mem_link)
        self.motor.calls = []
        self.seq = 0

    def _make_target(self, mem):
        if mem is None:
            return FakeI2CTarget(self.address, self.port)
        return FakeI2CTarget(self.address, self.port, mem=mem, mem_addrsize=V.MEM_ADDRSIZE)

    def _legacy(self):
        return I2CTargetAdapter(self.core, True)

    def tick(self):
        self.clock.advance(1000)
        self.core.service()
        if self.switch is not None:
            self.switch.service()

    def service_heap_locked(self):
        """The switch's main-loop pass with the heap locked (MicroPython: an allocation raises)."""
        heap_lock()
        try:
            self.switch.service()
        finally:
            heap_unlock()

    def run_ms(self, ms):
        for _ in range(ms):
            self.tick()

    @property
    def link(self):
        return self.switch.link

    def xfer(self, data, read_len):
        return self.switch.target.transfer(data, read_len)

    def legacy_command(self, name, *values):
        reg = P.register(name)
        return self.xfer(bytes([reg.addr]) + reg.encode(*values), 1)[0]

    def to_v2(self):
        self.legacy_command("PROTOCOL", 2)
        self.tick()
        assert self.switch.protocol == V.PROTOCOL_V2
        self.seq = self.link.ack

    def frame(self, name=None, *values, seq=None):
        """The mailbox bytes of a command (None: a NONE poll), with the next sequence number."""
        if seq is None:
            self.seq = (self.seq + 1) & V.SEQ_MASK
            seq = self.seq
        if name is None:
            return V.encode_frame(self.address, V.CMD_NONE, b"", seq)
        reg = P.register(name)
        return V.encode_frame(self.address, reg.addr, reg.encode(*values), seq)

    def exchange(self, frame):
        """One combined transaction, then one main-loop pass; the raw state bytes."""
        reply = self.xfer(frame, V.STATE_SIZE)
        self.tick()
        return reply

    def state(self):
        """A NONE poll; the decoded state the joint publishes after judging it. The main loop
        runs after each write: two in one pass are refused as a framing error."""
        self.exchange(self.frame())
        state = V.decode_state(self.address, self.xfer(self.frame(), V.STATE_SIZE))
        self.tick()
        return state

    def command(self, name, *values):
        """Send a command and return (verdict, flags) from the state after it was judged."""
        self.exchange(self.frame(name, *values))
        sent = self.seq
        flags, verdict, _, _, ack = V.decode_state(self.address, self.xfer(self.frame(), V.STATE_SIZE))
        self.tick()
        assert ack == sent, (ack, sent)
        return verdict, flags
