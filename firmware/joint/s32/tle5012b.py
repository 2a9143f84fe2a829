"""TLE5012B magnetic encoder over SSC (SPI3 with one data line), 15 bits a revolution.

One transfer (TLE5012B user's manual, SSC interface; chip select low for the whole transfer):

    MCU -> sensor   command word: bit 15 read, bits 14:11 lock, bit 10 update, bits 9:4 address,
                    bits 3:0 number of data words (ND)
    sensor -> MCU   ND data words, then the safety word

The data line is shared: the MCU sends the command on MOSI, then releases MOSI (an input) while the
sensor answers, as the uStepper library does. Angle register AVAL (0x02): bit 15 new-value flag,
bits 14:0 the angle (32768 counts a revolution). Safety word: bit 15 reset indicator, bits 14, 13, 12
LOW when a system error, an interface access error or an invalid angle is signalled, bits 7:0 a
CRC-8 (polynomial 0x1D, seed 0xFF, result inverted) over the command and data words, MSB first.
"""

from ..micro import const

READ_ANGLE = const(0x8021)  # read, address 0x02 (AVAL), one data word
SYSTEM_OK = const(0x4000)
ACCESS_OK = const(0x2000)
ANGLE_OK = const(0x1000)
COUNTS_PER_REV = const(32768)
ANGLE_MASK = const(0x7FFF)


def crc_table():
    """CRC-8 (polynomial 0x1D) of every byte value: four lookups check a reply at 1 kHz."""
    table = bytearray(256)
    for value in range(256):
        crc = value
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1D) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table[value] = crc
    return table


def crc8(table, buf, n):
    """The sensor's CRC of buf[0:n] (seed 0xFF, result inverted)."""
    crc = 0xFF
    for i in range(n):
        crc = table[crc ^ buf[i]]
    return crc ^ 0xFF


class TLE5012B:
    """Angle reads over a machine.SPI (mode 1, 16-bit words sent as byte pairs), a chip-select
    Pin and `release(on)`, which floats MOSI (on) or gives it back to the SPI (off)."""

    def __init__(self, spi, cs, release):
        self._spi = spi
        self._cs = cs
        self._release = release
        self._frame = bytearray(6)  # command, data, safety: the CRC runs over the first four
        self._frame[0] = READ_ANGLE >> 8
        self._frame[1] = READ_ANGLE & 0xFF
        self._command = memoryview(self._frame)[0:2]
        self._reply = memoryview(self._frame)[2:6]
        self._table = crc_table()
        self.errors = 0
        self.safety = 0  # the last safety word (bits 15:8) and CRC
        cs(1)

    def read_angle(self):
        """The 15-bit angle, or -1 when the safety word reports an error or its CRC is wrong."""
        cs = self._cs
        release = self._release
        cs(0)
        self._spi.write(self._command)
        release(1)
        self._spi.readinto(self._reply, 0xFF)
        release(0)
        cs(1)
        frame = self._frame
        self.safety = (frame[4] << 8) | frame[5]
        if (frame[4] & 0x70) != 0x70 or crc8(self._table, frame, 4) != frame[5]:
            self.errors += 1
            return -1
        return ((frame[2] << 8) | frame[3]) & ANGLE_MASK
