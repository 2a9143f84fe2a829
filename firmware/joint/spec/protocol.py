"""The Bioscara joint register protocol: the one spec shared by the joint firmware and the host.

This file runs unmodified under MicroPython (on the joint MCU) and CPython (host package
`bioscara.firmware.protocol`). It is wire-compatible with the original Arduino firmware:

* a command is one I2C write `[register, payload...]`, normally followed (repeated START) by a
  1-byte read of the flags;
* a register read is `[register]`, repeated START, then `payload + flags`;
* payloads are little-endian; floats are IEEE-754 binary32.

Each `Register` declares its write and read layout as `Field`s with units and valid ranges, whether
the command blocks (runs in the firmware main loop holding BUSY), and which flags it changes the
moment it is accepted. `Register.check_write` validates a payload without allocating, so the
firmware runs it inside the I2C IRQ and the host runs the very same check before sending.
"""

import struct
import sys



def crc32_bitwise(data, crc=0):
    """CRC-32 (zlib's, continuing from `crc` as zlib.crc32 does) bit by bit in 16-bit halves, so
    every step stays a small int: the spec hash on a port built without binascii.crc32 (the
    uStepper S32 image), computed once at boot."""
    hi = (crc >> 16) ^ 0xFFFF
    lo = (crc & 0xFFFF) ^ 0xFFFF
    for byte in data:
        lo ^= byte
        for _ in range(8):
            low_bit = lo & 1
            lo = (lo >> 1) | ((hi & 1) << 15)
            hi >>= 1
            if low_bit:
                hi ^= 0xEDB8
                lo ^= 0x8320
    return ((hi ^ 0xFFFF) << 16) | (lo ^ 0xFFFF)


try:
    from binascii import crc32
except ImportError:
    try:
        from zlib import crc32
    except ImportError:
        crc32 = crc32_bitwise

from .protocol_v2 import spec_bytes as _v2_spec_bytes
from ..micro import const

# Register docs are for people (the host's shell and docs); the board does not keep them (heap).
_KEEP_DOCS = sys.implementation.name != "micropython"

PROTOCOL_VERSION = const(2)  # the newest protocol this firmware serves (IDENTITY); see protocol_v2

ACK = const(0x4F)  # 'O', the PING payload
NACK = const(0x4E)  # 'N', declared by the original, never sent

# Flags byte, the last byte of every reply.
FLAG_STALL = const(0x01)  # stall detected, motor stopped; motion ignored until SETUP/ENABLESTALLGUARD
FLAG_BUSY = const(0x02)  # a blocking command (HOME, CHECKORIENTATION) is running
FLAG_NOTHOMED = const(0x04)
FLAG_NOTENABLED = const(0x08)
FLAG_ERROR = const(0x10)  # extension: the frame this reply answers was rejected (see LASTERROR)
FLAGS_AT_BOOT = const(0x0C)  # not homed, not enabled
FLAG_NAMES = (
    (FLAG_STALL, "STALL"),
    (FLAG_BUSY, "BUSY"),
    (FLAG_NOTHOMED, "NOTHOMED"),
    (FLAG_NOTENABLED, "NOTENABLED"),
    (FLAG_ERROR, "ERROR"),
)

# Host error codes of the original driver (uErr.h), value and message.
OK = const(0)
ERR_ERROR = const(-1)
ERR_NOT_HOMED = const(-2)
ERR_NOT_ENABLED = const(-3)
ERR_STALLED = const(-4)
ERR_NOT_INIT = const(-5)
ERR_COMM_ERROR = const(-6)
ERR_INVALID_ARGUMENT = const(-101)
ERR_INCORRECT_STATE = const(-109)
ERROR_CODES = (
    (OK, "OK", "no error"),
    (ERR_ERROR, "ERROR", "unspecified error"),
    (ERR_NOT_HOMED, "NOT_HOMED", "not homed"),
    (ERR_NOT_ENABLED, "NOT_ENABLED", "not enabled"),
    (ERR_STALLED, "STALLED", "stalled"),
    (ERR_NOT_INIT, "NOT_INIT", "not initialized"),
    (ERR_COMM_ERROR, "COMM_ERROR", "communication error"),
    (ERR_INVALID_ARGUMENT, "INVALID_ARGUMENT", "invalid argument"),
    (ERR_INCORRECT_STATE, "INCORRECT_STATE", "incorrect state (busy processing a blocking command)"),
)

# Why the firmware rejected a frame (extension, readable through LASTERROR).
REJECT_NONE = const(0)
REJECT_UNKNOWN_REGISTER = const(1)
REJECT_UNSUPPORTED = const(2)
REJECT_LENGTH = const(3)
REJECT_VALUE = const(4)
REJECT_BUSY = const(5)
REJECT_QUEUE_FULL = const(6)
REJECT_DISABLED = const(7)
REJECT_NOT_ENABLED = const(8)
REJECT_STALLED = const(9)
REJECT_HOMING_SENSITIVITY = const(10)
REJECT_REASONS = (
    (REJECT_NONE, "none"),
    (REJECT_UNKNOWN_REGISTER, "unknown register"),
    (REJECT_UNSUPPORTED, "register declared but not implemented"),
    (REJECT_LENGTH, "wrong payload length for this register"),
    (REJECT_VALUE, "value out of range or not finite"),
    (REJECT_BUSY, "a blocking command is already running"),
    (REJECT_QUEUE_FULL, "command queue full, command not accepted"),
    (REJECT_DISABLED, "joint disabled by an invalid configuration"),
    (REJECT_NOT_ENABLED, "motion refused: the joint is not enabled (SETUP enables it)"),
    (REJECT_STALLED, "motion refused: the joint is stalled (SETUP or ENABLESTALLGUARD re-arms it)"),
    (REJECT_HOMING_SENSITIVITY, "homing sensitivity at or below the joint's PID-error noise floor"),
)

# Field kinds: struct code and size.
U8 = const(1)
I32 = const(2)
F32 = const(3)
U16 = const(4)
U32 = const(5)
CHAR = const(6)
_CODES = {U8: ("B", 1), I32: ("i", 4), F32: ("f", 4), U16: ("H", 2), U32: ("I", 4), CHAR: ("B", 1)}


def _f32_halves(value):
    """Bit pattern of |value| as binary32, split into 16-bit halves (small ints on every port)."""
    bits = struct.unpack("<I", struct.pack("<f", abs(value)))[0]
    return bits >> 16, bits & 0xFFFF


class Field:
    """One value in a payload.

    U8 and U16 fields accept `lo <= value <= hi`. F32 fields accept a finite value whose magnitude lies in
    `[lo, hi]` (either sign: the original host sends negative limits for J2). I32 fields accept
    any value. CHAR and U32 fields only appear in replies.
    """

    # Defaults live in the class: on the board every instance attribute costs heap.
    unit = ""
    lo = 0
    hi = 0

    def __init__(self, name, kind, unit="", lo=0, hi=0):
        self.name = name
        self.kind = kind
        if unit:
            self.unit = unit
        if lo:
            self.lo = lo
        if hi:
            self.hi = hi
        if kind == F32:
            self._lo_hi16, self._lo_lo16 = _f32_halves(lo)
            self._hi_hi16, self._hi_lo16 = _f32_halves(hi)

    @property
    def code(self):
        """struct format character (derived, not stored: heap on the board)."""
        return _CODES[self.kind][0]

    @property
    def size(self):
        """Bytes on the wire."""
        return _CODES[self.kind][1]

    def check(self, buf, off):
        """True if the encoded value at buf[off:] is valid. Allocation-free (runs in the IRQ)."""
        kind = self.kind
        if kind == U8:
            return self.lo <= buf[off] <= self.hi
        if kind == U16:
            return self.lo <= (buf[off] | (buf[off + 1] << 8)) <= self.hi
        if kind == F32:
            b3 = buf[off + 3] & 0x7F
            b2 = buf[off + 2]
            if b3 == 0x7F and b2 & 0x80:
                return False  # NaN or infinity
            hi16 = (b3 << 8) | b2
            lo16 = (buf[off + 1] << 8) | buf[off]
            if hi16 < self._lo_hi16 or (hi16 == self._lo_hi16 and lo16 < self._lo_lo16):
                return False
            return hi16 < self._hi_hi16 or (hi16 == self._hi_hi16 and lo16 <= self._hi_lo16)
        return kind == I32

    def describe_range(self):
        if self.kind == U8 or self.kind == U16:
            return "%d..%d" % (self.lo, self.hi)
        if self.kind == F32:
            return "finite, |value| in [%g, %g]" % (self.lo, self.hi)
        return "any"


class Register:
    """One register of the joint: layouts, blocking behaviour and immediate flag effects.

    `sets`/`clears` are applied to the flags the moment the firmware accepts the frame, so the
    reply to a command already shows its effect (as the original firmware's reply did).
    `zero_sets` is applied when the first payload byte is 0 (a current of 0 disables the joint).
    """

    # Defaults live in the class and only other values in the instance: on the board every
    # instance attribute costs heap, and most registers keep most defaults.
    write = ()
    read = ()
    blocking = False
    sets = 0
    clears = 0
    zero_sets = 0
    supported = True
    doc = ""
    wsize = 0
    rsize = 0

    def __init__(self, addr, name, write=(), read=(), blocking=False, sets=0, clears=0,
                 zero_sets=0, supported=True, doc=""):
        self.addr = addr
        self.name = name
        if write:
            self.write = write
            self.wsize = sum(f.size for f in write)
        if read:
            self.read = read
            self.rsize = sum(f.size for f in read)
        if blocking:
            self.blocking = blocking
        if sets:
            self.sets = sets
        if clears:
            self.clears = clears
        if zero_sets:
            self.zero_sets = zero_sets
        if not supported:
            self.supported = supported
        if doc and _KEEP_DOCS:
            self.doc = doc

    @property
    def wfmt(self):
        """struct format of the write payload (built when asked: encode and decode allocate anyway)."""
        return "<" + "".join(f.code for f in self.write)

    @property
    def rfmt(self):
        return "<" + "".join(f.code for f in self.read)

    @property
    def readable(self):
        return self.supported and len(self.read) > 0

    @property
    def writable(self):
        return self.supported and len(self.write) > 0

    def check_write(self, buf, off, n):
        """Reject reason for the n-byte payload at buf[off:], REJECT_NONE if valid. Allocation-free."""
        if not self.supported:
            return REJECT_UNSUPPORTED
        if n != self.wsize or n == 0:
            return REJECT_LENGTH
        for f in self.write:
            if not f.check(buf, off):
                return REJECT_VALUE
            off += f.size
        return REJECT_NONE

    def encode(self, *values):
        """Payload bytes for a write of `values`; raises ValueError naming the offending field."""
        if not self.writable:
            raise ValueError("%s is not a writable register" % self.name)
        if len(values) != len(self.write):
            raise ValueError("%s takes %d values, got %d" % (self.name, len(self.write), len(values)))
        try:
            payload = struct.pack(self.wfmt, *values)
        except (struct.error, OverflowError, TypeError) as exc:
            raise ValueError("%s: cannot encode %r: %s" % (self.name, values, exc))
        off = 0
        for f, value in zip(self.write, values):
            if not f.check(payload, off):
                raise ValueError("%s.%s = %r is outside the valid range (%s)"
                                 % (self.name, f.name, value, f.describe_range()))
            off += f.size
        return payload

    def decode(self, payload):
        """Values of a read payload (the reply without its flags byte)."""
        if len(payload) != self.rsize:
            raise ValueError("%s reply payload must be %d bytes, got %d"
                             % (self.name, self.rsize, len(payload)))
        return struct.unpack(self.rfmt, payload)


_DEG = "deg (motor)"
_DEG_S = "deg/s (motor)"
_DEG_S2 = "deg/s^2 (motor)"
_LIMIT = 1e6
# Motor angles travel as Q12 degrees (fixed.py): |angle| < 2^18 degrees, about half of it kept for the
# homing offset added to an absolute target. A move beyond is refused (ERROR), never clamped.
_ANGLE_LIMIT = 131071.0
_ZERO_ONLY = Field("reserved", U8, "", 0, 0)


def _f32(name, unit, lo=0.0, hi=_LIMIT):
    return (Field(name, F32, unit, lo, hi),)


def _u8(name, unit, lo=0, hi=255):
    return (Field(name, U8, unit, lo, hi),)


def _unsupported(addr, name):
    return Register(addr, name, supported=False, doc="declared by the original, not implemented")


PING = const(0x0F)
SETUP = const(0x10)
SETRPM = const(0x11)
GETDRIVERRPM = const(0x12)
MOVESTEPS = const(0x13)
MOVEANGLE = const(0x14)
MOVETOANGLE = const(0x15)
GETMOTORSTATE = const(0x16)
RUNCOTINOUS = const(0x17)
ANGLEMOVED = const(0x18)
SETCURRENT = const(0x19)
SETHOLDCURRENT = const(0x1A)
SETMAXACCELERATION = const(0x1B)
SETMAXDECELERATION = const(0x1C)
SETMAXVELOCITY = const(0x1D)
ENABLESTALLGUARD = const(0x1E)
DISABLESTALLGUARD = const(0x1F)
CLEARSTALL = const(0x20)
SETBRAKEMODE = const(0x22)
ENABLEPID = const(0x23)
DISABLEPID = const(0x24)
ENABLECLOSEDLOOP = const(0x25)
DISABLECLOSEDLOOP = const(0x26)
SETCONTROLTHRESHOLD = const(0x27)
MOVETOEND = const(0x28)
STOP = const(0x29)
GETPIDERROR = const(0x2A)
CHECKORIENTATION = const(0x2B)
GETENCODERRPM = const(0x2C)
HOME = const(0x2D)
HOMEOFFSET = const(0x2E)
IDENTITY = const(0x30)
LASTERROR = const(0x31)
PROTOCOL = const(0x32)
HOMINGTRAVEL = const(0x33)
WATCHDOG = const(0x34)
HOMINGRESULT = const(0x35)
ENCODERZERO = const(0x36)
WATCHDOG_MAX_MS = const(5000)

BRAKE_FREEWHEEL = const(0)
BRAKE_COOLBRAKE = const(1)
BRAKE_HARDBRAKE = const(2)

REGISTERS = (
    Register(PING, "PING", read=(Field("ack", CHAR),), doc="liveness check, replies 'O'"),
    Register(SETUP, "SETUP",
             write=(Field("drive_current", U8, "%", 0, 100), Field("hold_current", U8, "%", 0, 100),
                    _ZERO_ONLY, _ZERO_ONLY),
             clears=FLAG_NOTENABLED | FLAG_STALL,
             doc="enable: currents, moveSteps(0), stall guard off, velocity setpoint 0"),
    Register(SETRPM, "SETRPM", write=_f32("rpm", "rpm (motor)", 0.0, 5000.0),
             doc="velocity mode; ignored while stalled or not enabled"),
    Register(GETDRIVERRPM, "GETDRIVERRPM", read=_f32("rpm", "rpm (driver ramp)"),
             doc="extension: ramp-generator speed (the original answered with flags only)"),
    Register(MOVESTEPS, "MOVESTEPS", write=(Field("steps", I32, "microsteps (1/256 step)"),),
             doc="relative move in the stepper library's step unit"),
    Register(MOVEANGLE, "MOVEANGLE", write=_f32("angle", _DEG, 0.0, _ANGLE_LIMIT),
             doc="extension: relative move"),
    Register(MOVETOANGLE, "MOVETOANGLE", write=_f32("angle", _DEG, 0.0, _ANGLE_LIMIT),
             doc="absolute move in the encoder frame; ignored while stalled or not enabled"),
    _unsupported(GETMOTORSTATE, "GETMOTORSTATE"),
    _unsupported(RUNCOTINOUS, "RUNCOTINOUS"),
    Register(ANGLEMOVED, "ANGLEMOVED", read=_f32("angle", _DEG), doc="encoder angle since home"),
    Register(SETCURRENT, "SETCURRENT", write=_u8("drive_current", "%", 0, 100),
             zero_sets=FLAG_NOTENABLED, doc="drive current; 0 disables"),
    Register(SETHOLDCURRENT, "SETHOLDCURRENT", write=_u8("hold_current", "%", 0, 100),
             zero_sets=FLAG_NOTENABLED, doc="hold current; 0 disables"),
    Register(SETMAXACCELERATION, "SETMAXACCELERATION", write=_f32("acceleration", _DEG_S2, 1e-3),
             doc="x 200/360 -> full steps/s^2, acceleration and deceleration"),
    Register(SETMAXDECELERATION, "SETMAXDECELERATION", write=_f32("deceleration", _DEG_S2, 1e-3),
             doc="extension: deceleration only"),
    Register(SETMAXVELOCITY, "SETMAXVELOCITY", write=_f32("velocity", _DEG_S, 1e-3),
             doc="x 200/360 -> full steps/s"),
    Register(ENABLESTALLGUARD, "ENABLESTALLGUARD", write=_u8("sensitivity", "x10 usteps"),
             clears=FLAG_STALL, doc="stall threshold = sensitivity x scale on the filtered PID error"),
    Register(DISABLESTALLGUARD, "DISABLESTALLGUARD", write=(_ZERO_ONLY,),
             doc="extension: stall detection off"),
    Register(CLEARSTALL, "CLEARSTALL", write=(_ZERO_ONLY,), clears=FLAG_STALL,
             doc="extension: clear STALL without re-enabling"),
    Register(SETBRAKEMODE, "SETBRAKEMODE", write=_u8("mode", "0 freewheel, 1 coolbrake, 2 hardbrake", 0, 2)),
    _unsupported(ENABLEPID, "ENABLEPID"),
    _unsupported(DISABLEPID, "DISABLEPID"),
    Register(ENABLECLOSEDLOOP, "ENABLECLOSEDLOOP", write=(_ZERO_ONLY,),
             doc="extension: closed loop on (SETUP is still needed to enable)"),
    Register(DISABLECLOSEDLOOP, "DISABLECLOSEDLOOP", write=(_ZERO_ONLY,), sets=FLAG_NOTENABLED),
    _unsupported(SETCONTROLTHRESHOLD, "SETCONTROLTHRESHOLD"),
    _unsupported(MOVETOEND, "MOVETOEND"),
    Register(STOP, "STOP", write=(_ZERO_ONLY,), clears=FLAG_BUSY,
             doc="RPM 0; clearing BUSY aborts a running HOME"),
    Register(GETPIDERROR, "GETPIDERROR", read=_f32("error", "usteps"),
             doc="extension: closed-loop error (driver - encoder)"),
    Register(CHECKORIENTATION, "CHECKORIENTATION", write=_f32("angle", _DEG, 1e-3, 360.0),
             blocking=True, sets=FLAG_BUSY, doc="wiring check by +/- angle moves"),
    Register(GETENCODERRPM, "GETENCODERRPM", read=_f32("rpm", "rpm (motor)"), doc="encoder speed"),
    Register(HOME, "HOME",
             write=(Field("direction", U8, "1 positive, 0 negative", 0, 1),
                    Field("speed", U8, "rpm (motor)", 1, 250),
                    Field("sensitivity", U8, "usteps (|PID error| end-stop threshold)", 0, 255),
                    Field("current", U8, "%", 0, 100)),
             blocking=True, sets=FLAG_BUSY | FLAG_NOTHOMED,
             doc="drive into the end stop and zero there"),
    Register(HOMEOFFSET, "HOMEOFFSET", write=_f32("offset", "joint units (opaque)"),
             read=_f32("offset", "joint units (opaque)"),
             doc="write stores, read returns; RAM only"),
    Register(IDENTITY, "IDENTITY",
             read=(Field("protocol", U8), Field("fw_major", U8), Field("fw_minor", U8),
                   Field("fw_patch", U8), Field("joint_id", U8), Field("spec_hash", U32)),
             doc="extension: protocol and firmware version, joint id, spec hash"),
    Register(LASTERROR, "LASTERROR",
             read=(Field("reason", U8), Field("register", U8), Field("count", U16)),
             doc="extension: why the last frame was rejected, and how many were"),
    Register(PROTOCOL, "PROTOCOL", write=(Field("protocol", U8, "1 legacy, 2 v2 memory map", 1, 2),),
             doc="extension: 2 makes the joint serve the v2 memory map (protocol_v2.py) from the "
                 "next main-loop pass; 1 (also a v2 command) or host silence returns it here"),
    Register(WATCHDOG, "WATCHDOG", write=(Field("timeout", U16, "ms", 0, WATCHDOG_MAX_MS),),
             read=(Field("timeout", U16, "ms"),),
             doc="extension: host-silence timeout for every motion mode (velocity, positioning, "
                 "homing, orientation check); 0 (boot): the original's, velocity only"),
    Register(HOMINGTRAVEL, "HOMINGTRAVEL", read=_f32("travel", _DEG),
             doc="extension: encoder travel of the last successful homing, start to end stop"),
    Register(HOMINGRESULT, "HOMINGRESULT", read=(Field("outcome", U8),),
             doc="extension: how the last HOME ended, an index of HOMING_OUTCOMES"),
    Register(ENCODERZERO, "ENCODERZERO", read=_f32("angle", _DEG),
             doc="extension: the encoder's own angle (0..360) where ANGLEMOVED is 0"),
)

# How a HOME ends (HOMINGRESULT; the joint logs the number, `bioscara console` these words).
HOMING_OUTCOMES = (
    "running",
    "homed",
    "travel limit reached without finding the end stop",
    "timeout without finding the end stop",
    "end stop found, but the sensitivity was not reached within the push time: lower it",
    "encoder too noisy at rest (weak or missing magnet): homing refused",
    "the joint did not come to rest before homing (a link falling under its load): homing refused",
    "encoder reports no magnet (or does not answer): homing refused",
    "encoder reports its magnet too weak (too far from the sensor): homing refused",
    "encoder reports its magnet too strong (too close to the sensor): homing refused",
)

BY_ADDR = [None] * 256
BY_NAME = {}
for _r in REGISTERS:
    BY_ADDR[_r.addr] = _r
    BY_NAME[_r.name] = _r

MAX_WRITE = max(r.wsize for r in REGISTERS)
MAX_READ = max(r.rsize for r in REGISTERS)
MAX_FRAME = 1 + MAX_WRITE  # register byte + payload
MAX_REPLY = MAX_READ + 1  # payload + flags


def register(key):
    """The Register for an address or a name; raises KeyError if the protocol has none."""
    reg = BY_ADDR[key] if isinstance(key, int) and 0 <= key < 256 else BY_NAME.get(key)
    if reg is None:
        raise KeyError("no register %r in protocol v%d" % (key, PROTOCOL_VERSION))
    return reg


def spec_hash(registers=REGISTERS):
    """CRC-32 over a canonical encoding of the register table (identical on both interpreters),
    fed a register at a time: a boot on a fragmented heap needs no block the size of the table."""
    out = bytearray(struct.pack("<BB", PROTOCOL_VERSION, ACK))
    for flag, name in FLAG_NAMES:
        out.append(flag)
        out.extend(name.encode())
    crc = crc32(out)
    for r in registers:
        out = bytearray(struct.pack("<BBBBBB", r.addr, r.supported, r.blocking, r.sets, r.clears,
                                    r.zero_sets))
        out.extend(r.name.encode())
        out.append(0)
        for group in (r.write, r.read):
            out.append(len(group))
            for f in group:
                out.extend(f.name.encode())
                out.append(0)
                out.append(f.kind)
                out.extend(f.unit.encode())
                out.append(0)
                out.extend(struct.pack("<ff", f.lo, f.hi))
        crc = crc32(out, crc)
    return crc32(_v2_spec_bytes(), crc) & 0xFFFFFFFF


SPEC_HASH = spec_hash()


def wire_bits(write_len, read_len):
    """Bit times of one transaction writing `write_len` bytes then reading `read_len` bytes."""
    bits = 1 + 9 * (1 + write_len) + 1
    if read_len > 0:
        bits += 1 + 9 * (1 + read_len)
    return bits


def describe_flags(flags):
    names = [name for bit, name in FLAG_NAMES if flags & bit]
    return "|".join(names) if names else "-"


def error_string(code):
    for value, _, text in ERROR_CODES:
        if value == code:
            return text
    return "unknown (%d)" % code


def reject_string(reason):
    for value, text in REJECT_REASONS:
        if value == reason:
            return text
    return "unknown reject reason %d" % reason


def homing_outcome_string(outcome):
    if 0 <= outcome < len(HOMING_OUTCOMES):
        return HOMING_OUTCOMES[outcome]
    return "unknown homing outcome %d" % outcome
