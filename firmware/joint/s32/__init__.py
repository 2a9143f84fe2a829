"""uStepper S32 motor backend: the TMC5130 driver (its own ramp generator) on SPI2 and the TLE5012B
15-bit encoder on SPI3, behind hal.MotorHAL (motor.S32Stepper), and the board's boot (board.py).
Imports the core's hal, fixed and velocity modules and MicroPython's machine; nothing from pico/
or sim/ (the S32 image freezes neither)."""
