"""Raspberry Pi Pico (RP2040/RP2350) motor backend: a TMC2209 driven by PIO step/dir pulses and
configured over its UART, with an AS5600 encoder on a second I2C bus (motor.PicoStepper)."""
