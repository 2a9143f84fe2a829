"""Boot the joint firmware on the MCU: configuration, motor backend, I2C target, main loop.

`machine` is passed in (the real module on the board, a stand-in in tests), so nothing here touches
hardware at import time. An invalid configuration or a motor backend that fails to start leaves
the joint disabled, reporting why on the serial console, instead of crashing.
"""

from . import micro
from .core.clock import MonotonicClock
from .core.controller import JointController
from .links.i2c_target import I2CTargetAdapter
from .console.log import Logger
from .spec.protocol_v2 import MEM_ADDRSIZE
from .config.settings import CONFIG_FILE
from .links.memmap_v2 import ProtocolSwitch

_SLOW_EVERY_MASK = 3  # the console and the legacy protocol switch: every 4th main-loop iteration


def board_module(path):
    return micro.board_module(__name__[:-len(".app")], path)


def build_motor(cfg):
    backend = cfg.motor.get("backend")
    if backend == "pico":
        return board_module("pico.motor").PicoStepper.from_config(cfg.motor)
    if backend == "s32":
        return board_module("s32.board").build_stepper(cfg.motor)
    raise ValueError("motor backend %r cannot run on a board" % cfg.motor.get("backend"))


def build(machine, config_path=CONFIG_FILE, clock=None, write=None, cfg=None, motor_builder=build_motor):
    """Load the configuration (unless `cfg` is given: a board without a filesystem) and create
    the controller; returns (core, cfg, log). `machine` None: no interrupt shares the core's state
    (CircuitPython polls its I2C target)."""
    if cfg is None:
        from .config import schema as config  # boot only (see _drop_boot_only)
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
    _drop_boot_only()
    return core, cfg, log


# Modules used only while building (package attribute paths under `joint`): the configuration's
# schema and checks, the Pico backend's defaults and validation, the register spec's objects, the
# builders of the controller and its IRQ tables (about 28 KB of heap together). The running joint
# keeps what it needs of them in settings.py's objects, regtable.RegisterTable and its own state.
BOOT_ONLY = ("config.schema", "core.controller_init", "core.irq_init", "pico.motor_config",
             "pico.tmc2209_setup", "spec.protocol", "spec.protocol_v2")


def _drop_boot_only():
    """On the board, forget the boot-only modules: out of sys.modules and their packages, their
    code and tables are collected. Importing one again simply reloads it."""
    import sys
    if sys.implementation.name == "cpython":
        return
    package = __name__[:-len("app")]  # "joint."
    for path in BOOT_ONLY:
        name = package + path
        if sys.modules.pop(name, None) is None:
            continue
        parent, leaf = name[:name.rindex(".")], name[name.rindex(".") + 1:]
        if hasattr(sys.modules.get(parent), leaf):
            delattr(sys.modules[parent], leaf)


def _on_rp2040(machine):
    import sys
    return (sys.platform == "rp2" and getattr(machine, "mem32", None) is not None
            and "RP2040" in getattr(sys.implementation, "_machine", ""))


def _on_stm32():
    import sys
    return sys.platform == "pyboard"


def bus_activity_probe(machine, bus):
    """A callable that is true while a transaction is in progress on target `bus`: the RP2040's
    activity bit; elsewhere none (always false: a torn state block is then caught by its CRC)."""
    mem32 = getattr(machine, "mem32", None)
    if _on_rp2040(machine):
        pico = board_module("pico")
        status = pico.i2c_registers(bus) + pico.IC_STATUS
        activity = pico.SLV_ACTIVITY

        def active():
            return mem32[status] & activity
        return active

    def never():
        return False
    return never


def join_bus(machine, core, cfg, log, target_pins=True):
    """Become an I2C target once booted, as the original registered its handlers last. Serves the
    legacy map; the returned ProtocolSwitch moves to v2 when the host asks (main loop).
    `target_pins`: pass the configured pins (rp2); the stm32 port's buses have fixed pins."""
    if cfg.address is None:
        log.error("no valid I2C address configured: not joining the bus")
        return None
    i2c = cfg.i2c

    def make_target(mem):
        pins = {"scl": machine.Pin(i2c.scl), "sda": machine.Pin(i2c.sda)} if target_pins else {}
        if mem is None:
            return machine.I2CTarget(i2c.bus, cfg.address, **pins)
        return machine.I2CTarget(i2c.bus, cfg.address, mem=mem, mem_addrsize=MEM_ADDRSIZE, **pins)

    probe = bus_activity_probe(machine, i2c.bus)
    # The legacy adapter sets the RX FIFO threshold and the RX_DONE mask in the target's I2C block.
    block = 0
    if _on_rp2040(machine):
        block = board_module("pico").i2c_registers(i2c.bus)

    def legacy_adapter(target):
        return I2CTargetAdapter(core, target, i2c.whole_reply_writes, probe, block, not _on_stm32())

    try:
        return ProtocolSwitch(core, cfg.address, make_target, legacy_adapter,
                              (machine.disable_irq, machine.enable_irq), lambda target: probe)
    except (ValueError, OSError, TypeError) as exc:
        log.error("cannot join the bus as I2C target 0x%02x on I2C%d (SDA %d, SCL %d): %r"
                  % (cfg.address, i2c.bus, i2c.sda, i2c.scl, exc))
        return None


def boot(machine, config_path=CONFIG_FILE, cfg=None):
    """`build`, then the boot task run to its end (the original's setup()); returns (core, cfg, log)."""
    import time

    core, cfg, log = build(machine, config_path, cfg=cfg)
    while not core.ready:
        core.service()
        time.sleep_ms(1)
    _drop_boot_only()  # again: the boot task's PicoStepper.begin loads pico.motor_config
    return core, cfg, log


def run(config_path=CONFIG_FILE, cfg=None, target_pins=True, console=True):
    """The joint's life: boot, join the bus, the 1 kHz main loop. A board without a filesystem
    passes its configuration as `cfg` and, with fixed bus pins, target_pins=False; one without
    room for the debug console, console=False (the log then prints to the REPL's serial port)."""
    import machine
    import time

    core, cfg, log = boot(machine, config_path, cfg)
    switch = join_bus(machine, core, cfg, log, target_pins)
    debug = None
    if console:
        console = board_module("console.debug")
        stdio = console.UsbStdio()
        log.set_writer(stdio.write)
        debug = console.DebugConsole(core, stdio.read, stdio.write)
    import gc
    gc.collect()
    log.info("booted: %d bytes of heap free" % gc.mem_free())  # the RAM left for the console and v2
    next_us = time.ticks_us()
    turn = 0
    try:
        while True:
            core.service()
            turn = (turn + 1) & _SLOW_EVERY_MASK
            # v2 serves its memory map every iteration; the legacy map only watches for a
            # PROTOCOL request, which may wait a few milliseconds.
            if switch is not None and (turn == 0 or switch.link is not None):
                switch.service()
            if turn == 0 and debug is not None:  # a person's console: every few milliseconds is quick enough
                try:
                    debug.poll()
                except Exception as exc:  # the console must never end the control loop
                    log.error("debug console: %r" % (exc,))
            # The next iteration starts 1 ms after this one's start: sleep_us waits to the
            # microsecond (machine.idle() on rp2, a tickless port, may resume up to 1 ms late).
            next_us = time.ticks_add(next_us, 1000)
            left = time.ticks_diff(next_us, time.ticks_us())
            if left > 0:
                time.sleep_us(left)
            elif left < -10000:
                next_us = time.ticks_us()  # fell behind (e.g. a long flash write): resynchronise
    except KeyboardInterrupt:
        # Ctrl-C (mpremote, or a stray byte): leave the joint safe before the REPL takes over,
        # since the deadman and stall detection stop with this loop.
        shut_down(core, switch, log)
        raise


def shut_down(core, switch, log):
    """Stop the motor, cut its current and leave the bus."""
    if switch is not None:
        switch.deinit()
    if core.hal is not None and not core.disabled:
        try:
            core.hal.stop(True)
            core.hal.set_current(0)
            core.hal.set_hold_current(0)
        except Exception as exc:
            log.error("shut down: %r" % (exc,))
    log.warn("stopped by Ctrl-C: motor off, joint off the bus")
