"""A simulated joint: the real firmware core and IRQ path driving a simulated stepper."""

from .. import config as joint_config
from ..core import JointController
from ..i2c_target import I2CTargetAdapter
from ..log import INFO, Logger
from .fixed_hal import FixedPointHAL
from .i2c_target import FakeI2CTarget


class SimJoint:
    """One joint MCU in simulation. `tick()` is one main-loop iteration at the clock's current time.

    The stepper (physical state: rotor angle, end stops) outlives `power_cycle()`, which reboots
    the firmware: the joint ignores its address until the boot sequence has finished, then comes
    back not homed and not enabled, exactly like a real joint after a brown-out.
    """

    def __init__(self, cfg, clock, stepper, port="rp2", write=None, level=INFO):
        if not cfg.valid:
            raise ValueError("; ".join(cfg.errors))
        self.cfg = cfg
        self.clock = clock
        self.stepper = stepper
        self.target = FakeI2CTarget(cfg.address, port)
        self.log = Logger(cfg.joint, level, write)
        self.boots = 0
        self.connected = True  # False: the bus cable is unplugged, the address does not ACK
        self.core = None
        self.adapter = None
        self.power_cycle()

    def power_cycle(self):
        self.target.deinit()
        self.adapter = None
        self.core = JointController(FixedPointHAL(self.stepper), self.clock, self.cfg, self.log)
        self.boots += 1

    @property
    def online(self):
        """True once the firmware has joined the bus (it ACKs its address) and the cable is in."""
        return self.connected and self.adapter is not None

    def tick(self):
        self.core.service()
        if self.adapter is None and self.core.ready:
            self.adapter = I2CTargetAdapter(self.core, self.target, self.cfg.i2c.whole_reply_writes)


def make_joint(joint, clock, stepper, **kwargs):
    """A SimJoint for J1..J4 with the default configuration."""
    return SimJoint(joint_config.default(joint), clock, stepper, **kwargs)
