"""The emulated Raspberry Pi Pico (rp2040js under node) that the chip tests and benchmarks run on."""
