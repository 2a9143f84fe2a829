"""The wiring of one joint board, generated from its joint configuration (`bioscara pins`).

A Raspberry Pi Pico per joint: the joint bus on its I2C target pins, a TMC2209 driver over UART
plus STEP/DIR/EN, an AS5600 encoder on the other I2C block. The pins are the configuration's
(`i2c` section, and `motor` over the Pico backend's defaults), so the table is always the one the
firmware will use.
"""

from __future__ import annotations

from .firmware.config import schema as firmware_config
from .firmware.pico.motor_config import DEFAULTS

Row = tuple[str, str, str]  # Pico pin, signal, connects to


def pin_map(cfg: firmware_config.JointConfig) -> list[Row]:
    """The rows of the wiring table for `cfg` (a validated joint configuration)."""
    m = dict(DEFAULTS)
    m.update({k: v for k, v in cfg.motor.items() if k != "backend"})
    bus = cfg.i2c
    return [
        (f"GP{bus.sda}", f"I2C{bus.bus} SDA (joint bus, target 0x{cfg.address:02x})",
         "joint bus SDA: Raspberry Pi GPIO2 (pin 3) or the HIL bridge's SDA"),
        (f"GP{bus.scl}", f"I2C{bus.bus} SCL (joint bus)", "joint bus SCL: Raspberry Pi GPIO3 (pin 5) or the HIL bridge's SCL"),
        (f"GP{m['uart_tx']}", f"UART{m['uart']} TX", f"TMC2209 PDN_UART through 1 kOhm ({m['uart_baud']} baud, "
         f"node address {m['tmc_address']}: MS1/MS2)"),
        (f"GP{m['uart_rx']}", f"UART{m['uart']} RX", "TMC2209 PDN_UART (directly)"),
        (f"GP{m['step']}", "STEP", "TMC2209 STEP"),
        (f"GP{m['dir']}", "DIR", "TMC2209 DIR"),
        (f"GP{m['enable']}", "EN (low = enabled)", "TMC2209 EN"),
        (f"GP{m['encoder_sda']}", f"I2C{m['encoder_i2c']} SDA (encoder)", "AS5600 SDA (pull-up on the AS5600 board)"),
        (f"GP{m['encoder_scl']}", f"I2C{m['encoder_i2c']} SCL (encoder)", "AS5600 SCL"),
        ("GND", "ground", "TMC2209 GND, AS5600 GND, joint bus GND (one common ground)"),
        ("3V3(OUT)", "3.3 V", f"TMC2209 VIO, AS5600 VCC (R_sense {m['rsense_ohm']} Ohm: 100 % = "
         f"{m['full_scale_ma']} mA RMS)"),
    ]


def markdown(cfg: firmware_config.JointConfig) -> str:
    """The wiring table as Markdown (docs/hardware.md holds the shipped configuration's)."""
    lines = ["| Pico pin | signal | connects to |", "|---|---|---|"]
    lines += [f"| {pin} | {signal} | {to} |" for pin, signal, to in pin_map(cfg)]
    return "\n".join(lines) + "\n"
