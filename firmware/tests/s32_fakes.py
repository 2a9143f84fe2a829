"""Register-level fakes of the uStepper S32's TMC5130 and TLE5012B, and a rotor between them.

They follow the datasheets' SPI frames: the TMC5130's 40-bit datagrams (bit 7 of the address
byte = write; every reply is SPI_STATUS plus the data of the previous read request) and the
TLE5012B's SSC transfer (command word, then data and safety word with its CRC while the MCU has
released MOSI). Everything on the 1 kHz path is integer arithmetic on preallocated state, so a
heap count under MicroPython sees only the firmware's allocations.

The ramp follows the TMC5130's in register units at fCLK = 10 MHz: per millisecond VACTUAL moves
toward its target by AMAX (DMAX when braking) x 625 / 8192 and XACTUAL by VACTUAL x 625 / 2**20.
The rotor follows the field (the position the ramp has driven, which XACTUAL writes do not
move) unless a wall stops it; past the wall it slips back a pole pitch (1024 usteps) whenever the
field leads by more than half of one (ustepper-model.md section 8.4, level 1).
"""

VERSION = 0x11
_N_REGS = 0x80
_WRAP = 0x3FFFFFFF
_SIGN = 0x20000000


def _signed30(b1, b2, b3, b4):
    x = ((b1 & 0x3F) << 24) | (b2 << 16) | (b3 << 8) | b4
    return x - _WRAP - 1 if x & _SIGN else x


class FakeTMC5130:
    """The chip: `spi` (machine.SPI) and `cs` (its Pin) as the firmware sees them."""

    def __init__(self, present=True):
        self.regs = [0] * _N_REGS
        self.present = present
        self.selected = False
        self.frames = 0
        self.writes = []  # (register, value) of every write, when `log_writes`
        self.log_writes = False
        self._pending = 0  # register the next reply reads
        self._acc_x = 0
        self._acc_v = 0
        self.v = 0  # VACTUAL, register units
        self.field = 0  # usteps the ramp has driven (XACTUAL writes leave it)
        self.regs[0x04] = VERSION << 24

    # ---- the firmware's side ----

    def cs(self, level):
        self.selected = not level

    def write_readinto(self, tx, rx):
        assert self.selected, "TMC5130 frame without chip select"
        assert len(tx) == 5 and len(rx) == 5, "TMC5130 datagrams are 40 bits"
        self.reply(rx)
        self.receive(tx[0], tx[1], tx[2], tx[3], tx[4])

    def reply(self, rx):
        """The five bytes the chip shifts out during a frame: SPI_STATUS and the pending read."""
        if not self.present:
            for i in range(5):
                rx[i] = 0xFF
            return
        value = self._read(self._pending)
        rx[0] = self.spi_status()
        rx[1] = (value >> 24) & 0xFF
        rx[2] = (value >> 16) & 0xFF
        rx[3] = (value >> 8) & 0xFF
        rx[4] = value & 0xFF

    def receive(self, addr, b1, b2, b3, b4):
        """A complete frame the MCU sent: a write, or the register the next frame returns."""
        self.frames += 1
        if addr & 0x80:
            self._write(addr & 0x7F, _signed30(b1, b2, b3, b4))
            self._pending = 0
        else:
            self._pending = addr & 0x7F

    def _read(self, reg):
        if reg == 0x22:
            return self.v & 0xFFFFFF  # VACTUAL: 24-bit two's complement
        return self.regs[reg]

    def _write(self, reg, value):
        self.regs[reg] = value
        if self.log_writes:
            self.writes.append((reg, value))

    def spi_status(self):
        r = self.regs
        standstill = self.v == 0
        reached = r[0x20] == 0 and r[0x21] == r[0x2D] and standstill
        return (0x08 if standstill else 0) | (0x20 if reached else 0)

    # ---- time ----

    def tick_ms(self):
        """One millisecond of the ramp generator."""
        r = self.regs
        mode = r[0x20]
        v = self.v
        vmax = r[0x27]
        if mode == 0:
            d = r[0x2D] - r[0x21]
            if d == 0 and -8 < v < 8:
                self.v = 0
                self._acc_v = 0
                return
            dmax = r[0x28] if r[0x28] > 0 else 1
            # usteps to stop from v: v**2 / DMAX / 2**8 (the datasheet's ramp length), in ints
            brake = (v >> 4) * (v >> 4) // dmax if v >= 0 else ((-v) >> 4) * ((-v) >> 4) // dmax
            toward = 1 if d > 0 else -1
            if v * toward > 0 and brake >= d * toward:
                target = 0
            else:
                target = toward * vmax
        else:
            target = vmax if mode == 1 else -vmax
        speeding_up = target > v >= 0 or target < v <= 0
        accel = r[0x26] if speeding_up or mode != 0 else r[0x28]  # velocity mode brakes with AMAX
        self._acc_v += accel * 625
        step = self._acc_v >> 13
        self._acc_v &= 8191
        if v < target:
            v = v + step if v + step < target else target
        elif v > target:
            v = v - step if v - step > target else target
        self.v = v
        self._acc_x += v * 625
        dx = self._acc_x >> 20 if self._acc_x >= 0 else -((-self._acc_x) >> 20)
        self._acc_x -= dx << 20
        if mode == 0:
            d = r[0x2D] - r[0x21]
            if (d - dx) * d <= 0:  # arrived (the fake stops at the target, whatever its speed)
                dx = d
                self.v = 0
                self._acc_x = 0
        r[0x21] += dx
        self.field += dx


class FakeTLE5012B:
    """The encoder: `spi` (SPI3 with one data line), `cs` and `release` (MOSI floated)."""

    def __init__(self, rotor):
        self.rotor = rotor
        self.selected = False
        self.released = False
        self.contention = 0  # replies the MCU drove MOSI over
        self.fault = 0  # safety-word bits (0x4000 system, 0x2000 access, 0x1000 angle) forced low
        self.corrupt_crc = False
        self.offset = 12345  # the magnet's angle at rotor 0, counts
        self._command = 0
        self._crc = _crc_table()

    def cs(self, level):
        self.selected = not level
        if level:
            self._command = 0

    def release(self, on):
        self.released = bool(on)

    def write(self, buf):
        assert self.selected and not self.released and len(buf) == 2
        self._command = (buf[0] << 8) | buf[1]

    def readinto(self, buf, fill=0):
        assert self.selected and len(buf) == 4
        if not self.released:
            self.contention += 1
        self.answer(self._command, buf)

    def answer(self, command, buf):
        """Data word and safety word (with its CRC) for `command`, into buf[0:4]."""
        angle = self.raw()
        data = 0x8000 | angle if command == 0x8021 else 0
        safety = 0x7000 & ~self.fault
        buf[0] = data >> 8
        buf[1] = data & 0xFF
        table = self._crc
        crc = table[table[table[table[0xFF ^ (command >> 8)] ^ (command & 0xFF)] ^ buf[0]] ^ buf[1]] ^ 0xFF
        if self.corrupt_crc:
            crc ^= 0x01
        buf[2] = safety >> 8
        buf[3] = crc
        if command & 0xF != 1 or (command >> 4) & 0x3F != 0x02:
            buf[2] &= ~0x20  # an access the fake does not serve: interface access error

    def raw(self):
        """The 15-bit angle of the rotor: 32768 counts per 51200 usteps."""
        r = self.rotor.position
        counts = (r * 16) // 25 if r >= 0 else -(((-r) * 16 + 24) // 25)
        return (counts + self.offset) & 0x7FFF


def _crc_table():
    """An independent CRC-8/0x1D table (a bitwise reference, MSB first)."""
    table = bytearray(256)
    for i in range(256):
        c = i
        for _ in range(8):
            c = (c << 1) ^ 0x11D if c & 0x80 else c << 1
        table[i] = c & 0xFF
    return table


class Rotor:
    """The motor shaft in usteps: follows the driver's field, or stops at a wall and slips."""

    def __init__(self, tmc):
        self.tmc = tmc
        self.wall = None  # usteps; the rotor cannot pass it in the direction of travel
        self.wall_side = 1
        self.position = 0

    def follow(self):
        f = self.tmc.field
        if self.wall is None:
            self.position = f
            return
        side = self.wall_side
        lead = (f - self.wall) * side
        if lead <= 512:
            self.position = f if lead <= 0 else self.wall
        else:  # the pole the field holds it at is past the wall: pressed there, or one behind
            slips = (lead - 512 + 1023) // 1024
            behind = (f - side * 1024 * slips - self.wall) * side
            self.position = self.wall if behind > 0 else f - side * 1024 * slips


class Board:
    """A TMC5130, a TLE5012B and a rotor, advanced a millisecond at a time."""

    def __init__(self, present=True):
        self.tmc = FakeTMC5130(present)
        self.rotor = Rotor(self.tmc)
        self.tle = FakeTLE5012B(self.rotor)

    def tick_ms(self):
        self.tmc.tick_ms()
        self.rotor.follow()
