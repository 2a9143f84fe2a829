"""Raspberry Pi Pico (RP2040/RP2350) motor backend: a TMC2209 driven by PIO step/dir pulses and
configured over its UART, with an AS5600 encoder on a second I2C bus (motor.PicoStepper).

May import motion, core.clock and micro; never a link, the core's contexts or sim. The package
itself holds the addresses of the chip's I2C blocks (the board loads it with the backend anyway),
which the encoder's reads and the legacy link's FIFO setup both use.
"""

IC_STATUS = 0x70  # DW_apb_i2c IC_STATUS, offset in the block
SLV_ACTIVITY = 0x40  # IC_STATUS: set while a transaction addressed to the target is in progress


def i2c_registers(index):
    """Address of the DW_apb_i2c block behind machine.I2C(index) (RP2040 or RP2350 datasheet)."""
    import sys

    base = 0x40090000 if "RP2350" in sys.implementation._machine else 0x40044000
    return base + index * (0x8000 if base == 0x40090000 else 0x4000)
