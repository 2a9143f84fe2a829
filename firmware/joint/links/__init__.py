"""How frames reach the core: the legacy map over MicroPython's I2CTarget IRQs (i2c_target.py),
the v2 memory map served from the main loop and the switch between the two (memmap_v2.py), and
CircuitPython's polled i2ctarget (cp_target.py). May import spec, core (its constants), motion
and micro."""
