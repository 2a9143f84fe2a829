"""The uStepper S32's boot: hardware objects from its pins, the configuration from flash.

No filesystem on this board (docs/s32.md): `bioscara flash --board s32` writes the joint's JSON
configuration into the last 4 KB of flash (CONFIG_ADDRESS, kept free by the board's linker
script), terminated by a 0xFF byte (erased flash) or a 0x00.

Pins (uStepper's Arduino variant): TMC5130 on SPI2 (PB13 SCK, PB14 MISO, PB15 MOSI, PB12 CS,
PA1 enable low, PC8 SD_MODE low and PC1 SPI_MODE high select its SPI/ramp mode); TLE5012B on
SPI3 (PC10 SCK, PC11 MISO, PC12 MOSI on the same data line, PA15 CS); the joint bus on I2C1.
"""

from ..micro import const

CONFIG_ADDRESS = const(0x0803F000)
CONFIG_SIZE = const(4096)
CONFIG_SOURCE = "flash 0x0803F000"
JOINT_BUS = const(1)  # I2C1: PB8 SCL, PB9 SDA

_GPIOC_MODER = const(0x40020800)
_MOSI3_SHIFT = const(24)  # PC12's two MODER bits
_SPI_BAUD = const(2_000_000)


def read_config(mem8, address=CONFIG_ADDRESS, size=CONFIG_SIZE):
    """The configuration bytes stored at `address` (up to the first 0xFF or 0x00)."""
    out = bytearray()
    for i in range(size):
        byte = mem8[address + i]
        if byte in (0xFF, 0x00):
            break
        out.append(byte)
    return bytes(out)


def load_config(mem8):
    from ..config import schema  # boot only (startup.BOOT_ONLY)
    return schema.parse_bytes(read_config(mem8), CONFIG_SOURCE)


def mosi_release(machine):
    """release(on) for the TLE5012B: PC12 as input (on) or back to its SPI3 alternate function
    (off), by its GPIOC MODER bits (a Pin.init per read would cost far more). PC14 and PC15 (the
    word's top bits) stay inputs on the S32, so the word is a small int and nothing allocates."""
    mem32 = machine.mem32
    shift = _MOSI3_SHIFT
    mask = ~(3 << shift)

    def release(on):
        moder = mem32[_GPIOC_MODER] & mask
        mem32[_GPIOC_MODER] = moder if on else moder | (2 << shift)
    return release


def build_stepper(motor_cfg):
    """S32Stepper on the board's SPI buses (motor_cfg: {"backend": "s32"}; nothing to set)."""
    import machine
    from .motor import S32Stepper
    from .tle5012b import TLE5012B
    from .tmc5130 import TMC5130

    pin = machine.Pin
    pin("PC8", pin.OUT, value=0)  # SD_MODE low: the TMC5130's own ramp generator
    pin("PC1", pin.OUT, value=1)  # SPI_MODE high: configured over SPI
    enable = pin("PA1", pin.OUT, value=1)
    driver = TMC5130(machine.SPI(2, baudrate=_SPI_BAUD, polarity=1, phase=1),
                     pin("PB12", pin.OUT, value=1))
    encoder = TLE5012B(machine.SPI(3, baudrate=_SPI_BAUD, polarity=0, phase=1),
                       pin("PA15", pin.OUT, value=1), mosi_release(machine))
    return S32Stepper(driver, encoder, enable)


def run():
    import machine
    from .. import app
    app.run(cfg=load_config(machine.mem8), target_pins=False, console=False)
