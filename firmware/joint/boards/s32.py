"""uStepper S32 (STM32F401RC, 256 KB flash, 64 KB RAM) on the project's MicroPython image
(`make s32-image`, docs/s32.md): these files are frozen into the image with MAIN, which starts
s32/board.py. The TMC5130 generates the ramp, so the per-tick software ramp stays out; so do the
Pico backend, the CircuitPython link and, for flash, the debug console (the log prints to the
REPL's UART). `bioscara flash --board s32` writes the image and the joint's configuration with
dfu-util instead of copying files."""

MAIN = "s32/main.py"
FILES = (
    "__init__.py", "app.py", "micro.py", "startup.py",
    "spec/", "core/", "config/", "s32/",
    "motion/__init__.py", "motion/fixed.py", "motion/hal.py", "motion/velocity.py",
    "detect/__init__.py", "detect/homing.py", "detect/load_angle.py", "detect/stall.py", "detect/tracking.py",
    "console/__init__.py", "console/log.py",
    "links/__init__.py", "links/i2c_target.py", "links/memmap_v2.py",
)
