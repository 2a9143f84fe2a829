"""HIL bridge: firmware for a USB MicroPython board as I2C controller, and the framing it shares with the host."""
