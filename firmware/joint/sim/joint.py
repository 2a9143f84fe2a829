"""A simulated joint: the real firmware core and I2C paths (legacy IRQ and v2 memory map)
driving a simulated stepper."""

import json

from ..config import schema as joint_config
from ..spec import protocol_v2 as V
from ..core.controller import NO_CRITICAL, JointController
from ..links.i2c_target import I2CTargetAdapter
from ..console.log import INFO, Logger
from ..links.memmap_v2 import ProtocolSwitch
from .fixed_hal import FixedPointHAL
from .i2c_target import FakeI2CTarget


class SimJoint:
    """One joint MCU in simulation. `tick()` is one main-loop iteration at the clock's current time.

    The stepper (physical state: rotor angle, end stops) outlives `power_cycle()`, which reboots
    the firmware: the joint ignores its address until the boot sequence has finished, then comes
    back not homed and not enabled, serving the legacy map, exactly like a real joint after a
    brown-out.
    """

    def __init__(self, cfg, clock, stepper, port="rp2", write=None, level=INFO, config_data=None):
        if not cfg.valid:
            raise ValueError("; ".join(cfg.errors))
        self.cfg = cfg
        self.config_data = config_data  # the decoded config file the joint holds (None: built in code)
        self.clock = clock
        self.stepper = stepper
        self.port = port
        self.log = Logger(cfg.joint, level, write)
        self.boots = 0
        self.connected = True  # False: the bus cable is unplugged, the address does not ACK
        self.core = None
        self.switch = None
        self.power_cycle()

    def power_cycle(self):
        if self.switch is not None:
            self.switch.deinit()
        self.switch = None
        self.core = JointController(FixedPointHAL(self.stepper), self.clock, self.cfg, self.log)
        self.boots += 1

    def config_file(self):
        """The joint's configuration file, as a host reads it over the board's USB (JSON bytes)."""
        if self.config_data is None:
            raise OSError("this simulated joint was built without a configuration file")
        return json.dumps(self.config_data).encode()

    def write_config_file(self, raw):
        """Replace the configuration file (as the board's file system does, whole); the firmware reads
        it at its next boot (power_cycle). ValueError, and nothing changes, when the firmware would
        refuse it."""
        cfg = joint_config.parse_bytes(raw, self.cfg.source)
        if not cfg.valid:
            raise ValueError("; ".join(cfg.errors))
        self.config_data = json.loads(raw)
        self.cfg = cfg

    @property
    def target(self):
        """The I2C target the joint serves now (the legacy IRQ target or the v2 memory)."""
        return self.switch.target

    @property
    def protocol(self):
        return self.switch.protocol if self.switch is not None else V.PROTOCOL_LEGACY

    @property
    def online(self):
        """True once the firmware has joined the bus (it ACKs its address) and the cable is in."""
        return self.connected and self.switch is not None

    def _make_target(self, mem):
        if mem is None:
            return FakeI2CTarget(self.cfg.address, self.port)
        return FakeI2CTarget(self.cfg.address, self.port, mem=mem, mem_addrsize=V.MEM_ADDRSIZE)

    def _legacy_adapter(self):
        return I2CTargetAdapter(self.core, self.cfg.i2c.whole_reply_writes)

    def tick(self):
        self.core.service()
        if self.switch is None:
            if self.core.ready:
                self.switch = ProtocolSwitch(self.core, self.cfg.address, self._make_target,
                                             self._legacy_adapter, NO_CRITICAL,
                                             _activity)
        else:
            self.switch.service()


def _activity(target):
    def active():
        return target.active
    return active


def shipped_config(joint, address=None, deadman_ms=None):
    """The shipped configuration of `joint` (J1..J4: config/J1.json ...) as a simulated joint runs
    it: every firmware constant of the file, on the simulated motor. The file's motor section and
    I2C pins are the board's (a Pico's backend and wiring), so the motor becomes the simulator's
    and the pins go unused; `address` and `deadman_ms`, when given, replace the file's (the host
    places the joint) and are checked like the file's own values."""
    return joint_config.parse(*shipped_data(joint, address, deadman_ms))


def shipped_data(joint, address=None, deadman_ms=None):
    """(decoded file, its path) of shipped_config."""
    path = __file__.rsplit("/", 2)[0] + "/config/" + joint + ".json"  # beside sim/, in the package
    with open(path) as f:
        data = json.load(f)
    data["motor"] = {"backend": "sim"}
    if address is not None:
        data["address"] = address
    if deadman_ms is not None:
        data["deadman_ms"] = deadman_ms
    return data, path


def make_joint(joint, clock, stepper, **kwargs):
    """A SimJoint for J1..J4 with the default configuration."""
    return SimJoint(joint_config.default(joint), clock, stepper, **kwargs)
