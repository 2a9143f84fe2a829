"""The I2C IRQ path: `machine.I2CTarget` hard-IRQ events to the joint core, allocation-free.

Event handling (see reference/i2c-facts.md section 1.4). Only the four events that carry work are
asked for: each event the handler takes costs a Python call inside the interrupt (tens of
microseconds on an RP2040), and on rp2 a read's first byte waits, SCL held low, for every call
still pending from the write before it.

* WRITE_REQ drains received bytes (one per event on most ports, a FIFO batch on rp2) straight into
  the preallocated frame buffer (past MAX_FRAME, an overlong frame's bytes are only counted);
  END_WRITE (at STOP or at the repeated START) takes what is left in the FIFO and hands the frame
  to the core, which validates and queues it, then starts the next frame. A write with no read is
  a complete command; a 0-byte write (address probe) ends with END_WRITE alone.
* The read's first READ_REQ asks the core for the reply (payload + flags, packed in advance by the
  main loop, the flags written in as of now); a read with no register written first repeats the
  last selected register. Each READ_REQ then feeds the reply: `write()` gets the rest of it at
  once, and the port takes what it can (one byte on most ports, up to the TX FIFO on rp2). The
  hardware asks for one byte past the end (prefetch, or rp2's RX_DONE), which gets a pad byte.
  END_READ closes the transaction.

The handler is one viper closure (`_handler`): on the chip an attribute lookup costs ~2.4 us and a
dispatch 11-18 us, so its state is an int32 array and its objects a tuple, and the reply selection
is kept here (`core.judge` judges a command; `core.on_frame` is the same for other callers).
"""

from array import array

from ..micro import const, micropython, ptr32, ptr8

from ..core.irq import FTAB_WLEN, REGISTER_SPACE
from ..spec.protocol import FLAG_ERROR, MAX_FRAME, PING


IRQ_ADDR_MATCH_READ = const(1)
IRQ_ADDR_MATCH_WRITE = const(2)
IRQ_READ_REQ = const(4)
IRQ_WRITE_REQ = const(8)
IRQ_END_READ = const(16)
IRQ_END_WRITE = const(32)
IRQ_ALL = const(63)
TRIGGER = const(60)  # READ_REQ | WRITE_REQ | END_READ | END_WRITE
_CHUNK = const(16)  # rp2 RX FIFO depth
COUNTER_MASK = const(0x1FFFFFFF)  # irq.COUNTER_MASK (viper needs this module's constants)
_MAX_FRAME = const(5)
_WLEN = const(64)  # where irq.py's frame table keeps each register's command frame length
_REGISTERS = const(64)  # every register address is below this


def _never():
    return False


# The adapter's state words (one int32 array: the handler reaches them through one pointer).
_S_LEN = const(0)  # frame bytes received so far
_S_READ = const(1)  # _IDLE, _READING or _OPEN
_S_POS = const(2)  # reply bytes handed to the port
_S_RLEN = const(3)  # the reply's length
_S_WHOLE = const(4)  # 1: write() takes a whole reply
_S_RX_TL = const(5)  # the RX FIFO threshold register's address (0: none, see I2CTargetAdapter)
_S_SEL = const(6)  # the reply the next read gets: a register address, or _SEL_FLAGS
_S_ERR = const(7)  # FLAG_ERROR if the frame the flags answer was rejected, else 0
_S_WROTE = const(8)  # a write ended since the last read ended (the transaction is counted)
_S_ADDR = const(9)  # the frame's first byte (its register)
_S_DRAIN = const(10)  # 1: END_WRITE drains the port's receive buffer (see I2CTargetAdapter)
_S_WLEN = const(16)  # by register: its command frame length (0: none)
_S_RSIZE = const(80)  # by register (and _SEL_FLAGS): its reply's length, payload + flags (0: none)
_S_WORDS = const(145)
_SEL_FLAGS = const(64)  # the flags alone
_IDLE = const(0)  # no read in progress
_READING = const(1)
_OPEN = const(2)  # no read in progress, a frame kept open (see I2CTargetAdapter)
# The RP2040's DW_apb_i2c (datasheet 4.3): register offsets, the atomic set/clear aliases.
_IC_INTR_MASK = const(0x30)
_IC_RX_TL = const(0x38)
_RXFLR_FROM_RX_TL = const(0x40)  # IC_RXFLR (0x78, the RX FIFO's level) from IC_RX_TL
_LAST_BYTE_SPINS = const(100)  # about 8 us on the RP2040 at 125 MHz
_M_RX_DONE = const(0x80)
_ATOMIC_SET = const(0x2000)
_ATOMIC_CLEAR = const(0x3000)
_RX_TL_BASE = const(0)  # the driver's: RX_FULL with the first byte (the driver's state machine needs it)
_ERROR = const(0x10)  # protocol.FLAG_ERROR
# The handler's objects, one tuple: entries 0..MAX_FRAME are where the next received bytes go, by
# frame length so far (an overlong frame's extra bytes land past MAX_FRAME), then these, then the
# reply wire buffers by register address (and _SEL_FLAGS).
_K_FRAME = const(6)
_K_JUDGE = const(7)
_K_TICKS_US = const(8)
_K_BUS_ACTIVE = const(9)
_K_ONE = const(10)
_K_PAD = const(11)
_K_WIRES = const(12)
if _MAX_FRAME != MAX_FRAME or _WLEN != FTAB_WLEN or _REGISTERS != REGISTER_SPACE or _ERROR != FLAG_ERROR:
    raise ImportError("i2c_target.py: constants differ from protocol.py / irq.py")


@micropython.viper
def _store32(address: int, value: int):
    ptr32(address)[0] = value


def _handler(s, core, k, flags_of):
    """The hard-IRQ handler, a viper closure: its cells cost less than attribute lookups (about
    2.4 us each on the chip), its state is the int32 array `s`, the rest the tuple `k`. At most 4
    cells: calling a closure with more (plus its argument) allocates (py/objclosure.c)."""

    @micropython.viper
    def irq(target):
        # The events in the order of their urgency: a READ_REQ holds SCL until it is answered.
        event = int(flags_of())  # one event per call
        st = ptr32(s)
        if event == IRQ_READ_REQ:
            if st[_S_READ] != _READING:  # the read's first request: the selected reply, flags as of now
                if st[_S_READ] == _OPEN:  # a frame kept open (see I2CTargetAdapter) ends here
                    length = st[_S_LEN]
                    st[_S_LEN] = 0
                    judge = k[_K_JUDGE]
                    st[_S_ERR] = _ERROR if int(judge(k[_K_FRAME], length)) else 0
                    st[_S_SEL] = _SEL_FLAGS
                sel = st[_S_SEL]
                wire = k[_K_WIRES + sel]
                n = st[_S_RSIZE + sel]
                ptr8(wire)[n - 1] = int(core.flags) | st[_S_ERR]
                if st[_S_WHOLE]:
                    sent = int(target.write(wire))
                else:
                    one = k[_K_ONE]
                    ptr8(one)[0] = ptr8(wire)[0]
                    sent = int(target.write(one))
                # SCL runs again once the port has the first byte: the bookkeeping comes after.
                st[_S_READ] = _READING
                st[_S_POS] = sent
                st[_S_RLEN] = n
                return
            pos = st[_S_POS]
            if pos < st[_S_RLEN]:  # a port that took less: the rest a byte at a time
                one = k[_K_ONE]
                ptr8(one)[0] = ptr8(k[_K_WIRES + st[_S_SEL]])[pos]
                st[_S_POS] = pos + int(target.write(one))
            else:
                target.write(k[_K_PAD])
            return
        length = st[_S_LEN]
        if event == IRQ_WRITE_REQ:
            buf = k[length if length < _MAX_FRAME else _MAX_FRAME]
            got = int(target.readinto(buf))
            if not got:
                # An RX_FULL in the snapshot whose bytes END_WRITE took (rp2 handles the repeated
                # START first): nothing arrived, and the frame it would size is closed.
                return
            if length == 0:
                st[_S_ADDR] = ptr8(buf)[0]
            length += got
            st[_S_LEN] = length
            if st[_S_RX_TL]:  # the next RX_FULL when the command's frame is whole
                addr = st[_S_ADDR]
                rest = (st[_S_WLEN + addr] if addr < _REGISTERS else 0) - length
                if rest == 1:
                    # The last byte lands within a byte time of the one before: at 400 kHz the
                    # call that took that one often ends a few us early, and an RX_FULL call for
                    # the last byte would cost ~28 us more. Waiting up to _LAST_BYTE_SPINS here
                    # takes it in this call instead.
                    level = ptr32(st[_S_RX_TL] + _RXFLR_FROM_RX_TL)
                    spins = 0
                    while level[0] == 0 and spins < _LAST_BYTE_SPINS:
                        spins += 1
                    if level[0]:
                        got = int(target.readinto(k[length if length < _MAX_FRAME else _MAX_FRAME]))
                        length += got
                        st[_S_LEN] = length
                        rest -= got
                ptr32(st[_S_RX_TL])[0] = rest - 1 if rest > 1 else 0
            return
        if event == IRQ_END_WRITE:
            # END_WRITE drains too: rp2 handles a repeated START before the RX data that came with
            # it, so the last bytes of a command can still be in the FIFO (chip/README.md).
            buf = k[length if length < _MAX_FRAME else _MAX_FRAME]
            got = 0
            if st[_S_DRAIN]:
                got = int(target.readinto(buf))
            if length == 0 and got:
                st[_S_ADDR] = ptr8(buf)[0]
            length += got
            addr = st[_S_ADDR]
            if length == 1 and addr < _REGISTERS and st[_S_RSIZE + addr]:
                st[_S_SEL] = addr  # selected for reading (on_frame's first case)
                st[_S_ERR] = 0
            elif length:
                if length < _MAX_FRAME and addr < _REGISTERS and length < st[_S_WLEN + addr]:
                    bus_active = k[_K_BUS_ACTIVE]
                    if bus_active():
                        st[_S_LEN] = length  # cut short by the driver: the rest follows
                        st[_S_READ] = _OPEN
                        if st[_S_RX_TL]:
                            rest = st[_S_WLEN + addr] - length
                            ptr32(st[_S_RX_TL])[0] = rest - 1 if rest > 1 else 0
                        return
                judge = k[_K_JUDGE]
                st[_S_ERR] = _ERROR if int(judge(k[_K_FRAME], length)) else 0
                st[_S_SEL] = _SEL_FLAGS
            if st[_S_RX_TL]:
                ptr32(st[_S_RX_TL])[0] = _RX_TL_BASE
            st[_S_LEN] = 0
            st[_S_READ] = _IDLE  # (an _OPEN frame closed here was empty)
            st[_S_WROTE] = 1
        else:  # END_READ: the transaction was counted at its write, if it had one
            st[_S_READ] = _IDLE
            if st[_S_WROTE]:
                st[_S_WROTE] = 0
                return
        ticks_us = k[_K_TICKS_US]
        core.host_us = ticks_us()  # host_seen(), inlined: the deadman counts from here
        core.transactions = (int(core.transactions) + 1) & COUNTER_MASK

    return irq


class I2CTargetAdapter:
    """Connects a `machine.I2CTarget` (or the simulator's fake) to a JointController: built first
    (the handler's tables), then `attach(target)`.

    `whole_reply_writes=False` hands `write()` one byte at a time, for ports whose `write()`
    reports 1 even when it queued more (alif).

    `end_write_drains=False` for ports whose every received byte comes with its own WRITE_REQ and
    whose `readinto()` reads the data register whether or not a byte arrived (stm32: an END_WRITE
    drain there would count the last byte twice).

    `bus_active()` is true while a transaction addressed to the target is in progress (the RP2040's
    activity bit, app.bus_activity_probe). The rp2 driver reads its interrupt status once per
    interrupt: when a STOP is serviced late, after the next transaction's START and first byte, it
    ends that transaction's write (END_WRITE) after its first bytes. A command frame that ends
    short while the bus is still active is therefore kept open: the rest of it follows, and a read
    (repeated START) closes it as it is.

    `rp2040_i2c` is the RP2040 I2C block's base address (app.py; 0: another port). Each event
    costs a Python call (11-18 us on the chip) and the adapter saves two there, through the
    peripheral's registers:

    * A fast handler takes a command's bytes one RX_FULL interrupt each. Once the register byte
      is in (the first RX_FULL: the driver only ends a write that had one), the RX FIFO threshold
      (IC_RX_TL) is raised so that the next RX_FULL comes when the register's frame is whole, and
      set back to 0 (the driver's value) when the write ends. A write-only frame shorter than its
      register's then waits in the FIFO (the driver keeps its STOP pending) until the next
      transaction starts, which ends that write first: it is malformed and rejected all the same.
      When one byte is left (a 2-byte command), the call waits up to about 8 us for it (IC_RXFLR)
      and takes it: at 400 kHz it lands a few us after the register byte's call, which saves the
      call its RX_FULL would cost (2-byte commands 158 -> 125 us of IRQ CPU at worst).
    * RX_DONE (the controller's NAK after a read's last byte) is masked in IC_INTR_MASK: the
      driver only answers it with one more READ_REQ, whose pad byte never reaches the wire (it
      is flushed at the next read). A read longer than its reply still gets its pad bytes (each
      one a READ_REQ). The driver changes the mask bit by bit, so the bit stays cleared.

    A transaction is counted (`core.transactions`, `core.host_us` for the deadman) once, at the
    end of its write, or at the end of its read if it had no write (a read-only transaction right
    after a write-only one is not counted).
    """

    def __init__(self, core, whole_reply_writes=True, bus_active=None, rp2040_i2c=0, end_write_drains=True):
        frame = bytearray(MAX_FRAME + _CHUNK)
        view = memoryview(frame)
        wires = core._wires + [core._flags_wire]
        # Made now because slicing in the IRQ would allocate. Each has room for a whole RX FIFO.
        k = tuple([view[i:] for i in range(MAX_FRAME + 1)]) + (
            frame, core.judge, core._ticks_us, bus_active or _never, bytearray(1), bytearray(1)
        ) + tuple(wires)
        if len(k) != _K_WIRES + _SEL_FLAGS + 1:
            raise ImportError("i2c_target.py: the handler's object table is out of order")
        st = self._state = array("i", [0] * _S_WORDS)
        st[_S_WHOLE] = 1 if whole_reply_writes else 0
        st[_S_DRAIN] = 1 if end_write_drains else 0
        st[_S_RX_TL] = rp2040_i2c + _IC_RX_TL if rp2040_i2c else 0
        st[_S_SEL] = PING
        for addr in range(_REGISTERS):
            st[_S_WLEN + addr] = core._ftab[_WLEN + addr]
        for sel, wire in enumerate(wires):
            st[_S_RSIZE + sel] = len(wire) if wire else 0
        self._rp2040_i2c = rp2040_i2c
        self._core = core
        self._k = k
        self._target = None

    def attach(self, target):
        """Serve `target`. A target acknowledges its address from its creation on, and until its
        handler is set a read gets zeros: ProtocolSwitch creates it only once the tables above
        are built (their allocation can start a collection, tens of ms on the chip)."""
        self._target = target
        # The irq object first: a host already polling at boot fires the handler the moment it is set.
        self._irq = _handler(self._state, self._core, self._k, target.irq().flags)
        target.irq(self._irq, trigger=TRIGGER, hard=True)
        if self._rp2040_i2c:
            _store32(self._rp2040_i2c + _ATOMIC_CLEAR + _IC_INTR_MASK, _M_RX_DONE)

    def deinit(self):
        self._target.irq(None, trigger=0, hard=True)
        base = self._rp2040_i2c
        if base:
            _store32(base + _IC_RX_TL, 0)
            _store32(base + _ATOMIC_SET + _IC_INTR_MASK, _M_RX_DONE)
