"""Raspberry Pi Pico (RP2040) on stock MicroPython >= 1.26: the joint serves the bus through
machine.I2CTarget (legacy IRQs, then the v2 memory map) and drives a TMC2209 by PIO step/dir
with an AS5600 encoder (the pico backend)."""

MAIN = "board_main.py"
FILES = (
    "__init__.py", "app.py", "micro.py", "startup.py",
    "spec/", "core/", "motion/", "detect/", "console/", "config/", "pico/",
    "links/__init__.py", "links/i2c_target.py", "links/memmap_v2.py",
)
