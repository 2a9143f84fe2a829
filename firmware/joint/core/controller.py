"""Joint controller core: register semantics, flags, blocking commands, stall detection, deadman.

`JointController` composes the core's contexts, one module each:

* `irq.py` (IRQ path: `on_frame`, `reply_wire`, `host_seen`): never allocates; validates frames,
  updates flags, queues commands, serves replies packed in advance;
* `loop.py` (main loop: `service`): drains the queue into the motor HAL through the register
  handlers of `handlers.py`, steps the blocking tasks of `tasks.py` (boot, HOME,
  CHECKORIENTATION), runs the supervision of `supervise.py` (stall detection, deadman) and
  refreshes the reply caches.

No hardware module is imported here: the HAL, clock, logger and IRQ masking are injected.
"""

from .handlers import Handlers
from .irq import COUNTER_MASK, IrqPath
from .loop import MainLoop
from .supervise import Supervisor
from .tasks import Tasks

__all__ = ("COUNTER_MASK", "JointController", "NO_CRITICAL")


def _no_irq_off():
    return 0


def _no_irq_on(state):
    pass


# The (disable, enable) pair where nothing is shared with an interrupt (v2, the simulator).
NO_CRITICAL = (_no_irq_off, _no_irq_on)


class JointController(IrqPath, MainLoop, Handlers, Tasks, Supervisor):
    """The firmware of one joint, independent of the I2C peripheral and the motor backend."""

    def __init__(self, hal, clock, cfg, log, critical=None):
        from .controller_init import init  # boot only (startup.BOOT_ONLY)
        init(self, hal, clock, cfg, log, critical)

    def set_critical(self, critical):
        """The (disable, enable) interrupt pair guarding state shared with the IRQ path; None:
        nothing to guard (protocol v2: no Python IRQ, and the I2C interrupt must never be held
        off while a transaction is in progress, see ProtocolSwitch)."""
        self._irq_off, self._irq_on = critical or NO_CRITICAL

    def _select_protocol(self, q, off):
        self.protocol_request = q[off]


def _flatten(cls):
    """Copy the mixins' methods into `cls`'s own dictionary (the first base that defines a name
    wins, as in the method resolution order). MicroPython looks a method up base after base on
    every call: about 40 us on the chip for one of the last mixin's, 5 us in the class itself."""
    own = [name for name in cls.__dict__]
    for base in reversed(cls.__bases__):
        for name, value in base.__dict__.items():
            if not name.startswith("__") and name not in own:
                setattr(cls, name, value)
    return cls


_flatten(JointController)
