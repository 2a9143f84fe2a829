"""Simulation backends for the joint firmware: virtual clock, fake I2C target, simulated stepper."""
