"""Run the joint firmware on the MCU: boot (startup.py, forgotten once done), join the bus as an
I2C target, the main loop.

`machine` is passed in (the real module on the board, a stand-in in tests), so nothing here touches
hardware at import time.
"""

from . import micro
from .links.i2c_target import I2CTargetAdapter
from .spec.protocol_v2 import MEM_ADDRSIZE
from .config.settings import CONFIG_FILE
from .links.memmap_v2 import ProtocolSwitch

_SLOW_EVERY_MASK = 3  # the console and the legacy protocol switch: every 4th main-loop iteration
# The console's first command imports its commands, whose names grow MicroPython's never-freed
# interned-string pool by one block of about 7.7 KB in one piece. The boot-only modules leave the
# heap in holes of at most 7 KB, so the boot keeps this much in one piece from its start, and
# frees it at its end: free heap all the same, but one piece the pool can take.
_CONSOLE_ROOM = 10240


def board_module(path):
    return micro.board_module(__name__[:-len(".app")], path)


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

    def legacy_adapter():
        return I2CTargetAdapter(core, i2c.whole_reply_writes, probe, block, not _on_stm32())

    between, mem_link = probe, None
    if _on_stm32():  # v2 publishes its state block between reads from this joint (s32/v2.py)
        v2 = board_module("s32.v2")
        between, mem_link = v2.read_in_progress(machine.mem32, i2c.bus), v2.S32MemLink
    try:
        return ProtocolSwitch(core, cfg.address, make_target, legacy_adapter,
                              (machine.disable_irq, machine.enable_irq), lambda target: between, mem_link)
    except (ValueError, OSError, TypeError) as exc:
        log.error("cannot join the bus as I2C target 0x%02x on I2C%d (SDA %d, SCL %d): %r"
                  % (cfg.address, i2c.bus, i2c.sda, i2c.scl, exc))
        return None


def run(config_path=CONFIG_FILE, cfg=None, target_pins=True, console=True):
    """The joint's life: boot, join the bus, the 1 kHz main loop. A board without a filesystem
    passes its configuration as `cfg` and, with fixed bus pins, target_pins=False; one without
    room for the debug console, console=False (the log then prints to the REPL's serial port)."""
    import machine
    import time

    room = bytearray(_CONSOLE_ROOM) if console else None
    from . import startup  # boot only: forgotten at the end of its boot()
    core, cfg, log = startup.boot(machine, config_path, cfg)
    del startup
    switch = join_bus(machine, core, cfg, log, target_pins)
    debug = None
    if console:
        console = board_module("console.debug")
        stdio = console.UsbStdio()
        log.set_writer(stdio.write)
        debug = console.DebugConsole(core, stdio.read, stdio.write)
    import gc
    room = None
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
