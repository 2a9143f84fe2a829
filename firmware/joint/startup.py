"""The joint's boot, before the main loop: configuration, motor backend, controller, boot task.

Boot only: `build` and `boot` end by forgetting the modules in BOOT_ONLY, this one among them, so
the running joint keeps none of this code on its heap (about 0.7 KB on a Pico). Nothing the running
joint holds may be made here: a function object keeps its module's globals, and with them all of
its code (the bus's target makers are app.py's for that reason).
`machine` is passed in (the real module on the board, a stand-in in tests), so nothing here
touches hardware at import time. An invalid configuration or a motor backend that fails to start
leaves the joint disabled, reporting why on the serial console, instead of crashing.
"""

from . import micro
from .core.clock import MonotonicClock
from .core.controller import JointController
from .console.log import Logger
from .config.settings import CONFIG_FILE

_ROOT = __name__[:-len(".startup")]  # "joint" on a board, "bioscara.firmware" on the host

# Modules used only while booting (package attribute paths under `joint`): this one, the
# configuration's schema and checks, the Pico backend's defaults and validation, the register
# spec's objects, the builders of the controller and its IRQ tables (about 29 KB of heap together).
# The running joint keeps what it needs of them in settings.py's objects, regtable.RegisterTable
# and its own state.
BOOT_ONLY = ("startup", "config.schema", "core.controller_init", "core.irq_init", "pico.motor_config",
             "pico.tmc2209_setup", "spec.protocol", "spec.protocol_v2")


def build_motor(cfg):
    backend = cfg.motor.get("backend")
    if backend == "pico":
        return micro.board_module(_ROOT, "pico.motor").PicoStepper.from_config(cfg.motor)
    if backend == "s32":
        return micro.board_module(_ROOT, "s32.board").build_stepper(cfg.motor)
    raise ValueError("motor backend %r cannot run on a board" % cfg.motor.get("backend"))


def build(machine, config_path=CONFIG_FILE, clock=None, write=None, cfg=None, motor_builder=build_motor):
    """Load the configuration (unless `cfg` is given: a board without a filesystem) and create
    the controller; returns (core, cfg, log). `machine` None: no interrupt shares the core's state
    (CircuitPython polls its I2C target)."""
    if cfg is None:
        from .config import schema as config  # boot only
        cfg = config.load(config_path)
    log = Logger(cfg.joint or "joint", write=write)
    motor = None
    if cfg.valid:
        try:
            motor = motor_builder(cfg)
        except Exception as exc:
            cfg.errors.append("motor backend failed to start: %r" % (exc,))
    critical = None if machine is None else (machine.disable_irq, machine.enable_irq)
    core = JointController(motor, clock or MonotonicClock(), cfg, log, critical=critical)
    drop_boot_only()
    return core, cfg, log


def boot(machine, config_path=CONFIG_FILE, cfg=None):
    """`build`, then the boot task run to its end (the original's setup()); returns (core, cfg, log)."""
    import time

    core, cfg, log = build(machine, config_path, cfg=cfg)
    while not core.ready:
        core.service()
        time.sleep_ms(1)
    drop_boot_only()  # again: the boot task's PicoStepper.begin loads pico.motor_config
    return core, cfg, log


def drop_boot_only():
    """On the board, forget the boot-only modules: out of sys.modules and their packages, their
    code and tables are collected. Importing one again simply reloads it."""
    import sys
    if sys.implementation.name == "cpython":
        return
    for path in BOOT_ONLY:
        name = _ROOT + "." + path
        if sys.modules.pop(name, None) is None:
            continue
        parent, leaf = name[:name.rindex(".")], name[name.rindex(".") + 1:]
        if hasattr(sys.modules.get(parent), leaf):
            delattr(sys.modules[parent], leaf)
