# What the uStepper S32 image freezes: the joint firmware without the Pico backend, the simulator,
# the CircuitPython link, the software ramp (the TMC5130 generates its own) and the debug console
# (the log prints to the REPL's UART). opt=3 drops line numbers and asserts (flash is the budget: docs/s32.md).
_JOINT = (
    "__init__.py", "app.py", "clock.py", "config.py", "core.py", "core_init.py",
    "emitters.py", "fixed.py", "hal.py", "handlers.py", "homing.py", "i2c_target.py", "irq.py",
    "irq_init.py", "log.py", "loop.py", "protocol.py", "protocol_v2.py", "regtable.py",
    "settings.py", "stall.py", "supervise.py", "tasks.py", "tracking.py", "v2.py", "velocity.py",
    "version.py",
    "s32/__init__.py", "s32/board.py", "s32/motor.py", "s32/tle5012b.py", "s32/tmc5130.py",
)
package("joint", files=_JOINT, base_path="$(BOARD_DIR)/../..", opt=3)
module("main.py", opt=3)
