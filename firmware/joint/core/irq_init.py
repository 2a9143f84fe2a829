"""The IRQ path's tables, built from the protocol spec at boot only (startup.BOOT_ONLY): the board
forgets this code once the joint is built; irq.py's viper code keeps reading what it made.

The frame table (`core._ftab`, one bytearray so viper code reaches it through one pointer): by
register address (every register is below REGISTERS; any other address is unknown), the reject
reason whatever the payload (or REJECT_NONE), the frame length a payload needs, how the payload is
checked, the spec's flag effects, what the joint's state may refuse, then the payload limits, then
the state the judge reads, kept here where it is written (a byte here costs the viper code no
attribute lookup, 2.4 us each on the chip, and no method call, 20-40 us), and LASTERROR's wire
buffer, where the judge records a rejection. irq.py has the same offsets as its own constants
(test_irq_path checks).
"""

from .irq import FTAB_DISABLED, QUEUE_SLOTS, SLOT, judge_for
from ..spec.protocol import (
    BY_ADDR, F32, HOME, I32, LASTERROR, MOVEANGLE, MOVESTEPS, MOVETOANGLE, PING, REJECT_LENGTH,
    REJECT_UNKNOWN_REGISTER, REJECT_UNSUPPORTED, SETRPM, U8, U16,
)

REGISTERS = 64
PRE = 0
WLEN = 64
CHECK = 128
SETS = 192
CLEARS = 256
ZERO_SETS = 320
BLOCKS = 384
REFUSE = 448  # MOTION or HOMING
LO = 512  # CHECK_BYTES: payload byte i within [LO, HI] at addr*4 + i
HI = 768
LIMITS = 1024  # CHECK_F32: the |value| limits as 16-bit halves (low high16, low low16,
#                high high16, high low16), little-endian, at addr*8; CHECK_U16: low, high
DISABLED = 1536  # 1 if the joint is disabled
STOPS = 1537  # the stop epoch
HALTS = 1538  # the halt epoch
# Whether a blocking command is live (queued or running, not cancelled by a STOP since), 8-bit
# counters and epochs: BLOCK_IN counts the blocking commands accepted, BLOCK_OUT those the main
# loop took from the queue, BLOCK_STOPS is the stop epoch of the latest accepted; TASK is 1 while
# a task runs (the main loop), TASK_STOPS the stop epoch it belongs to.
BLOCK_IN = 1539
BLOCK_OUT = 1540
BLOCK_STOPS = 1541
TASK = 1542
TASK_STOPS = 1543
HOMING_FLOOR = 1544  # HOME's sensitivity noise floor: threshold + speed x per_rpm (Q10 / 1024),
HOMING_FLOOR_Q = 1546  # both 16-bit little-endian (boot only)
LASTERROR_WIRE = 1548  # LASTERROR's wire buffer (reason, register, count u16, flags): the judge records here
# The command queue's counters (8 bits: slot = counter % QUEUE_SLOTS), commands accepted (IRQ) and
# applied (main loop); REARMS counts the frames that cleared STALL (a stall decided before one
# is dropped).
Q_IN = 1553
Q_OUT = 1554
REARMS = 1555
SIZE = 1556
MOTION = 1  # refused while stalled or not enabled (SETRPM: unless 0 rpm)
HOMING = 2  # refused at or below the homing sensitivity noise floor

CHECK_BYTES = 0  # every field U8
CHECK_F32 = 1  # one F32 field: finite, |value| within the limits
CHECK_U16 = 2  # one U16 field
CHECK_ANY = 3  # one I32 field: any value


def payload_check(reg):
    """The check kind for a register's write fields; ValueError if the tables cannot check them."""
    kinds = [f.kind for f in reg.write]
    if all(k == U8 for k in kinds) and len(kinds) <= 4:
        return CHECK_BYTES
    if kinds == [F32]:
        return CHECK_F32
    if kinds == [U16]:
        return CHECK_U16
    if kinds == [I32]:
        return CHECK_ANY
    raise ValueError("the IRQ frame tables cannot check register %s" % reg.name)


def _put16(table, off, value):
    table[off] = value & 0xFF
    table[off + 1] = value >> 8


def frame_table():
    """The frame table (layout above) for the protocol's registers."""
    t = bytearray(SIZE)
    for addr in range(256):
        reg = BY_ADDR[addr]
        if addr >= REGISTERS:
            if reg is not None:
                raise ValueError("register %s is outside the IRQ frame table" % reg.name)
        elif reg is None:
            t[PRE + addr] = REJECT_UNKNOWN_REGISTER
        elif not reg.supported:
            t[PRE + addr] = REJECT_UNSUPPORTED
        elif reg.wsize == 0:
            t[PRE + addr] = REJECT_LENGTH
        else:
            kind = payload_check(reg)
            t[WLEN + addr] = 1 + reg.wsize
            t[CHECK + addr] = kind
            t[SETS + addr] = reg.sets
            t[CLEARS + addr] = reg.clears
            t[ZERO_SETS + addr] = reg.zero_sets
            t[BLOCKS + addr] = reg.blocking
            if addr in (SETRPM, MOVETOANGLE, MOVEANGLE, MOVESTEPS):
                t[REFUSE + addr] = MOTION
            elif addr == HOME:
                t[REFUSE + addr] = HOMING
            if kind == CHECK_BYTES:
                for i, f in enumerate(reg.write):
                    t[LO + addr * 4 + i] = f.lo
                    t[HI + addr * 4 + i] = f.hi
            elif kind == CHECK_F32:
                f = reg.write[0]
                for i, half in enumerate((f._lo_hi16, f._lo_lo16, f._hi_hi16, f._hi_lo16)):
                    _put16(t, LIMITS + addr * 8 + 2 * i, half)
            elif kind == CHECK_U16:
                _put16(t, LIMITS + addr * 8, reg.write[0].lo)
                _put16(t, LIMITS + addr * 8 + 2, reg.write[0].hi)
    return t


def init(core, homing_floor, homing_floor_q):
    """`core`'s IRQ side (irq.IrqPath): the frame table, wire buffers for the reply caches (LASTERROR's
    in the table), the command queue, the judge. `homing_floor` (PID-error usteps) and
    `homing_floor_q` (usteps per rpm, Q10) give HOME's sensitivity noise floor."""
    ftab = core._ftab = frame_table()
    ftab[FTAB_DISABLED] = 1 if core.disabled else 0
    for off, value in ((HOMING_FLOOR, homing_floor), (HOMING_FLOOR_Q, homing_floor_q)):
        if not 0 <= value <= 0xFFFF:
            raise ValueError("homing noise floor %d outside the IRQ's 16 bits" % value)
        _put16(ftab, off, value)
    if LASTERROR_WIRE + len(core._cache[LASTERROR]) + 1 != Q_IN:
        raise ValueError("LASTERROR does not fit its place in the IRQ frame table")
    core._wires = [None] * REGISTERS
    for addr in range(len(core._cache)):
        cache = core._cache[addr]
        if cache is not None:
            n = len(cache)
            wire, at = (ftab, LASTERROR_WIRE) if addr == LASTERROR else (bytearray(n + 1), 0)
            wire[at:at + n] = cache
            view = memoryview(wire)[at:at + n + 1]
            core._cache[addr] = view[:n]  # the main loop packs here, as before
            core._wires[addr] = view
    core._flags_wire = memoryview(bytearray(1))
    core._queue = bytearray(QUEUE_SLOTS * SLOT)
    core.judge = judge_for(core, core._ftab, core._queue)
    core._reply_wire = core._wires[PING]
    core._reply_err = 0
