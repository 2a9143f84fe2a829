"""Protocol v2: the memory-mapped joint. Part of the one spec (see protocol.py), shared unmodified.

The joint serves one 15-byte memory through `machine.I2CTarget(mem=..., mem_addrsize=0)`: the
peripheral's C code answers every byte, no Python runs while SCL is held. With `mem_addrsize=0`
every write starts at offset 0 (the command mailbox) and the read that follows the repeated START
continues where the write stopped, which is the state block. One combined transaction per joint
per cycle therefore sends a command and returns the state:

    START addr+W | mailbox (7 bytes) | Sr addr+R | state (8 bytes) | STOP       156 bit times

Mailbox (offset 0, written by the host):

    0  cmd      legacy register address of the command; 0 = NONE (a poll, nothing applied)
    1  payload  the legacy register's payload (same encoding, units, ranges), zero-padded to 4
    5  crc      CRC-8/SMBUS over (address << 1 | W), cmd, payload, seq
    6  seq      frame sequence number 0..127; bit 7 is always 0

State (offset 7, written by the joint):

    7  status   bit 7 always 1; bits 4-6 the verdict of the latest frame (REASON_*); bits 0-3 the
                legacy flags STALL, BUSY, NOTHOMED, NOTENABLED
    8  position int24, motor angle since home in 1/64 deg (legacy ANGLEMOVED), saturated
    11 velocity int15 + bit 15 always 1: encoder speed in 1/8 rpm (legacy GETENCODERRPM),
                saturated at +/-2048 rpm
    13 ack      seq of the latest frame that passed the link checks; bit 7 always 0
    14 crc      CRC-8/SMBUS over (address << 1 | R), bytes 7..13

The marker bits make the cheap corruptions deterministic, not merely unlikely: a write one byte
too long puts the mailbox's last byte (bit 7 clear) over the status byte (bit 7 set); a read that
ends early reads 0xFF (released SDA) where ack must have bit 7 clear; a byte slipped into a read
before the ack pushes the velocity's high byte (bit 7 set) into the ack. The host takes a state
only if its ack is exactly the frame it sent before (so a replayed block never gets in). The
address in both CRCs rejects a frame that reached the wrong joint through a flipped address bit.
CRC-8/SMBUS catches every error of up to 3 bits in these frames. The joint applies a frame only
if it is new: 1..63 ahead of `ack` (7-bit arithmetic). The same frame again (a retry) is ignored without
changing the verdict; anything else behind or equal is a sequence error.
"""

from ..micro import const

PROTOCOL_LEGACY = const(1)
PROTOCOL_V2 = const(2)

MAILBOX = const(0)
MAILBOX_SIZE = const(7)
STATE = const(7)
STATE_SIZE = const(8)
MEM_SIZE = const(15)
MEM_ADDRSIZE = const(0)

M_CMD = const(0)
M_PAYLOAD = const(1)
M_CRC = const(5)
M_SEQ = const(6)
PAYLOAD_SIZE = const(4)

S_STATUS = const(7)
S_POSITION = const(8)
S_VELOCITY = const(11)
S_ACK = const(13)
S_CRC = const(14)

CMD_NONE = const(0)
SEQ_MASK = const(0x7F)
SEQ_WINDOW = const(64)  # a frame 1..63 ahead of ack is new; anything else is old
STATUS_MARKER = const(0x80)
STATUS_FLAGS = const(0x0F)
REASON_SHIFT = const(4)
REASON_MASK = const(0x70)

POSITION_Q = const(6)  # 1/64 deg
VELOCITY_Q = const(3)  # 1/8 rpm
POSITION_MAX = const(0x7FFFFF)
VELOCITY_MAX = const(0x3FFF)
VELOCITY_MARKER = const(0x80)  # in the velocity's high byte

# How long a v2 joint waits for its host before it serves the legacy map again (ms).
SILENCE_MS = const(2000)

# The verdict of the latest frame, in the status byte.
REASON_OK = const(0)
REASON_CRC = const(1)  # link: CRC mismatch
REASON_SEQUENCE = const(2)  # link: stale or repeated sequence number
REASON_FRAME = const(3)  # link: frame too long or too short
REASON_COMMAND = const(4)  # unknown, unsupported or non-writable command
REASON_VALUE = const(5)  # payload out of range (the legacy register's check)
REASON_BUSY = const(6)  # a blocking command is running, or the command queue is full
REASON_DISABLED = const(7)  # joint disabled (invalid configuration, motor fault), or motion refused
# while not enabled or stalled
REASONS = (
    (REASON_OK, "ok"),
    (REASON_CRC, "CRC mismatch"),
    (REASON_SEQUENCE, "stale or repeated sequence number"),
    (REASON_FRAME, "frame too long or too short"),
    (REASON_COMMAND, "not a v2 command"),
    (REASON_VALUE, "value out of range"),
    (REASON_BUSY, "busy or command queue full"),
    (REASON_DISABLED, "joint disabled, not enabled or stalled"),
)
LINK_REASONS = (REASON_CRC, REASON_SEQUENCE, REASON_FRAME)

# Legacy reject reason -> v2 verdict.
# Motion refused while not enabled or stalled shares REASON_DISABLED: the status flags say which.
FROM_LEGACY = bytes((REASON_OK, REASON_COMMAND, REASON_COMMAND, REASON_COMMAND, REASON_VALUE,
                     REASON_BUSY, REASON_BUSY, REASON_DISABLED, REASON_DISABLED, REASON_DISABLED,
                     REASON_VALUE))

# The state block's fields, declared like the legacy registers' (name, kind, unit, scale).
STATE_FIELDS = (
    ("status", "u8", "bit 7 marker, bits 4-6 verdict, bits 0-3 flags", 1),
    ("position", "i24", "deg (motor), since home", 1 << POSITION_Q),
    ("velocity", "i15+marker", "rpm (motor), encoder", 1 << VELOCITY_Q),
    ("ack", "u8", "sequence number of the latest frame that passed the link checks", 1),
    ("crc", "u8", "CRC-8/SMBUS", 1),
)
MAILBOX_FIELDS = (
    ("cmd", "u8", "legacy register address, 0 = NONE", 1),
    ("payload", "4 bytes", "the legacy register's payload, zero-padded", 1),
    ("crc", "u8", "CRC-8/SMBUS", 1),
    ("seq", "u8", "0..127", 1),
)


def _crc_table():
    table = bytearray(256)
    for value in range(256):
        crc = value
        for _ in range(8):
            crc = ((crc << 1) ^ 0x07) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table[value] = crc
    return bytes(table)


CRC_TABLE = _crc_table()  # CRC-8/SMBUS of each byte value (v2.py keeps it past boot)


def crc8(buf, start, end, crc=0):
    """CRC-8/SMBUS (poly 0x07, init 0, no reflection) of buf[start:end], continuing `crc`.

    Allocation-free, one table lookup per byte: the firmware runs it in its main loop."""
    table = CRC_TABLE
    for i in range(start, end):
        crc = table[crc ^ buf[i]]
    return crc


def crc8_byte(value, crc=0):
    return CRC_TABLE[crc ^ value]


def mailbox_crc(buf, off, address):
    """The CRC a mailbox at buf[off:] must carry, for the joint at `address`."""
    crc = crc8_byte(address << 1)
    crc = crc8(buf, off + M_CMD, off + M_CRC, crc)
    return crc8_byte(buf[off + M_SEQ], crc)


def state_crc(buf, off, address):
    """The CRC a state block at buf[off:] must carry (`off` is where its status byte is)."""
    return crc8(buf, off, off + STATE_SIZE - 1, crc8_byte((address << 1) | 1))


def is_command(reg):
    """True if the legacy Register `reg` (None: no such register) may travel in the mailbox:
    writable, with a payload of at most 4 bytes."""
    return reg is not None and reg.writable and reg.wsize <= PAYLOAD_SIZE


def sign_extend(value, bits):
    if value & (1 << (bits - 1)):
        return value - (1 << bits)
    return value


def reason_string(reason):
    for value, text in REASONS:
        if value == reason:
            return text
    return "unknown verdict %d" % reason


def spec_bytes():
    """A canonical encoding of this layout, covered by the spec hash (protocol.spec_hash)."""
    out = bytearray((PROTOCOL_V2, MAILBOX, MAILBOX_SIZE, STATE, STATE_SIZE, MEM_ADDRSIZE,
                     M_CMD, M_PAYLOAD, M_CRC, M_SEQ, S_STATUS, S_POSITION, S_VELOCITY, S_ACK,
                     S_CRC, POSITION_Q, VELOCITY_Q, SEQ_WINDOW, STATUS_MARKER, VELOCITY_MARKER))
    for group in (STATE_FIELDS, MAILBOX_FIELDS):
        for name, kind, unit, scale in group:
            out.extend(name.encode())
            out.extend(kind.encode())
            out.extend(unit.encode())
            out.append(scale)
    for value, text in REASONS:
        out.append(value)
        out.extend(text.encode())
    return bytes(out)


TRANSACTION_BITS = const(156)  # protocol.wire_bits(MAILBOX_SIZE, STATE_SIZE)


def encode_frame(address, cmd, payload, seq):
    """The mailbox bytes of one frame to the joint at `address` (host side; allocates).

    `payload` is the legacy register's encoded payload (Register.encode), at most 4 bytes."""
    if len(payload) > PAYLOAD_SIZE:
        raise ValueError("a v2 command carries at most %d payload bytes" % PAYLOAD_SIZE)
    buf = bytearray(MAILBOX_SIZE)
    buf[M_CMD] = cmd
    for i in range(len(payload)):
        buf[M_PAYLOAD + i] = payload[i]
    buf[M_SEQ] = seq & SEQ_MASK
    buf[M_CRC] = mailbox_crc(buf, 0, address)
    return bytes(buf)


def decode_state(address, data):
    """(flags, verdict, position, velocity, ack) of a state block read from the joint at
    `address`, position in 1/64 deg and velocity in 1/8 rpm; None if the block is corrupt."""
    v = S_VELOCITY - STATE
    if (len(data) != STATE_SIZE or not data[0] & STATUS_MARKER or data[S_ACK - STATE] & 0x80
            or not data[v + 1] & VELOCITY_MARKER):
        return None
    if state_crc(data, 0, address) != data[STATE_SIZE - 1]:
        return None
    p = S_POSITION - STATE
    position = sign_extend(data[p] | (data[p + 1] << 8) | (data[p + 2] << 16), 24)
    velocity = sign_extend(data[v] | ((data[v + 1] & 0x7F) << 8), 15)
    return (data[0] & STATUS_FLAGS, (data[0] & REASON_MASK) >> REASON_SHIFT, position, velocity,
            data[S_ACK - STATE])
