"""Bioscara joint firmware (MicroPython). Copied onto each joint MCU as the package `joint`."""
