"""Raspberry Pi Pico (RP2040) on stock CircuitPython 10: the joint serves the legacy map through
i2ctarget, polled by its loop (links/cp_target.py), and drives the same TMC2209, PIO step/dir
and AS5600 through busio, rp2pio and digitalio (cpy/). `bioscara flash --runtime circuitpython`
copies these files onto CIRCUITPY under /lib/joint, and MAIN as /code.py. startup.py is the shared
boot; app.py gives the shut-down (it imports the MicroPython links, which the CircuitPython joint
never starts)."""

MAIN = "cpy/board_code.py"
FILES = (
    "__init__.py", "app.py", "micro.py", "startup.py",
    "spec/", "core/", "motion/", "detect/", "console/", "config/", "pico/",
    "cpy/__init__.py", "cpy/app.py", "cpy/clock.py", "cpy/fixed.py", "cpy/hardware.py",
    "links/__init__.py", "links/cp_target.py", "links/i2c_target.py", "links/memmap_v2.py",
)
