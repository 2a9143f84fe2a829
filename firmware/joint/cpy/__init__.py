"""CircuitPython on a Raspberry Pi Pico: the Pico joint's hardware (TMC2209 on UART, STEP/DIR from
PIO, AS5600 on the second I2C, the joint bus on GP4/GP5) through CircuitPython's busio, rp2pio,
digitalio and i2ctarget, driving the unchanged core and pico.motor.PicoStepper. Imports the
firmware's core, links and pico backend; CircuitPython modules only inside functions."""
