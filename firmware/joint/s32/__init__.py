"""uStepper S32 motor backend: the TMC5130 driver (its own ramp generator) on SPI2 and the TLE5012B
15-bit encoder on SPI3, behind hal.MotorHAL (motor.S32Stepper), and the board's boot (board.py).
Imports motion/ (the HAL, the velocity estimator), config/ (at boot), app (to run) and micro; never
pico/, sim/ or the console (the S32 image freezes none of them)."""
