"""The I2C IRQ path: hardware event sequences, allocation-free handling, ordering of queued commands.

Under the MicroPython unix port the fake target runs every handler call inside
`micropython.heap_lock()`, as a hard IRQ does, so any allocation fails the handler.
"""

import struct
import sys

from joint.spec import protocol as P
from joint.sim.i2c_target import FakeI2CTarget
from joint.links.i2c_target import I2CTargetAdapter
from harness import Rig

MICROPYTHON = sys.implementation.name == "micropython"
A_MW, A_MR, RQ, WQ, E_R, E_W = 2, 1, 4, 8, 16, 32


class EventLog:
    """A handler that logs events into a preallocated buffer and echoes one byte."""

    def __init__(self, target):
        self._log = bytearray(32)
        self._count = 0
        self.buf = bytearray(1)
        target.irq(self.handle, trigger=63, hard=True)

    def handle(self, target):
        flags = target.irq().flags()
        self._log[self._count] = flags
        self._count += 1
        if flags & WQ:
            target.readinto(self.buf)
        if flags & RQ:
            target.write(self.buf)

    def take(self):
        events = list(self._log[:self._count])
        self._count = 0
        return events


def test_event_sequences_match_the_hardware():
    for port in ("rp2", "stm32"):
        target = FakeI2CTarget(0x11, port)
        log = EventLog(target)
        target.transfer(b"", 0)
        assert log.take() == [A_MW, E_W], "scan is a 0-byte write"
        target.transfer(b"XYZ", 0)
        assert log.take() == [A_MW, WQ, WQ, WQ, E_W]
        target.transfer(None, 1)
        assert log.take() == [A_MR, RQ, RQ, E_R], "N-byte read: N+1 READ_REQ (%s)" % port
        target.transfer(b"X", 1)
        assert log.take() == [A_MW, WQ, E_W, A_MR, RQ, RQ, E_R], "write, repeated START, read"
        assert target.handler_failures == 0


def test_rp2_fifo_serves_a_whole_reply_from_one_read_request():
    rig = Rig(port="rp2")
    reads = []
    original = rig.target.write

    def counting_write(buf):
        reads.append(len(buf))
        return original(buf)
    rig.target.write = counting_write
    assert rig.xfer(bytes([P.ANGLEMOVED]), 5) == struct.pack("<f", 0.0) + bytes([0x0C])
    assert reads[0] == 5, "the whole reply is offered to write() at once"


def test_every_port_and_write_mode_gives_identical_replies():
    replies = []
    for port, whole in (("rp2", True), ("rp2", False), ("stm32", True), ("stm32", False)):
        rig = Rig(port=port, whole_reply_writes=whole)
        rig.motor.angle = -123.5
        rig.run_ms(1)
        replies.append((rig.xfer(bytes([P.ANGLEMOVED]), 5), rig.xfer(bytes([P.IDENTITY]), 10),
                        rig.command("SETUP", 10, 10, 0, 0)))
        rig.assert_handler_alive()
    assert all(r == replies[0] for r in replies), replies
    assert replies[0][0] == struct.pack("<f", -123.5) + bytes([0x0C])


def test_read_without_a_register_repeats_the_last_one():
    rig = Rig()
    rig.motor.angle = 5.0
    rig.run_ms(1)
    first = rig.xfer(bytes([P.ANGLEMOVED]), 5)
    rig.motor.angle = 6.0
    rig.run_ms(1)
    assert rig.xfer(None, 5) == struct.pack("<f", 6.0) + first[-1:]


def test_write_without_read_is_a_complete_command():
    rig = Rig()
    rig.xfer(bytes([P.SETUP, 20, 20, 0, 0]), 0)
    rig.run_ms(1)
    assert rig.core.flags == 0x04
    assert ("set_current", 20) in rig.motor.calls


def test_longer_and_shorter_reads_than_the_reply():
    rig = Rig()
    assert rig.xfer(bytes([P.PING]), 4) == bytes([ord("O"), 0x0C, 0, 0]), "padded past the reply"
    assert rig.xfer(bytes([P.PING]), 1) == b"O"


def test_every_register_read_and_write_runs_without_allocation():
    rig = Rig()
    for addr in range(256):
        reg = P.BY_ADDR[addr]
        payload = bytes(reg.wsize) if reg is not None and reg.wsize else b"\x00\x00\x00\x00"
        for data, read_len in ((bytes([addr]), 10), (bytes([addr]) + payload, 1),
                               (bytes([addr]) + payload, 0), (None, 10), (bytes([addr]), 0)):
            rig.xfer(data, read_len)
        rig.run_ms(1)
    rig.assert_handler_alive()


def test_an_allocating_handler_would_be_caught():
    target = FakeI2CTarget(0x11)

    def allocating(t):
        t.irq().flags()
        return [1, 2, 3]
    target.irq(allocating, trigger=63, hard=True)
    target.transfer(b"\x0f", 1)
    if MICROPYTHON:
        assert target.handler_failures == 1 and not target.handler_installed, "heap_lock is active"
    else:
        assert target.handler_failures == 0


def test_commands_are_applied_in_arrival_order():
    rig = Rig()
    rig.command("SETUP", 20, 20, 0, 0)
    for rpm in (1.0, 2.0, 3.0):
        rig.command("SETRPM", rpm)
    rig.command("MOVESTEPS", 7)
    rig.command("SETCURRENT", 30)
    rig.run_ms(1)
    assert rig.motor.calls[3:] == [("set_rpm", 1.0), ("set_rpm", 2.0), ("set_rpm", 3.0),
                                   ("move_steps", 7), ("set_current", 30)]


def test_stop_is_immediate_and_discards_motion_queued_before_it():
    rig = Rig()
    rig.command("SETUP", 20, 20, 0, 0)
    rig.run_ms(1)
    rig.motor.calls = []
    rig.command("SETRPM", 50.0)
    rig.command("MOVESTEPS", 9)
    rig.command("STOP", 0)
    rig.command("SETRPM", 5.0)
    rig.run_ms(1)
    assert [c for c in rig.motor.calls if c[0] in ("set_rpm", "move_steps")] == [
        ("set_rpm", 0), ("set_rpm", 5.0)], "STOP first, then only what came after it"


def test_stop_is_never_refused_even_with_a_full_queue():
    rig = Rig()
    rig.command("SETUP", 20, 20, 0, 0)
    rig.run_ms(1)
    rig.command("SETRPM", 100.0)
    rig.run_ms(1)
    while not rig.command("SETCURRENT", 20) & P.FLAG_ERROR:
        pass
    assert not rig.command("STOP", 0) & P.FLAG_ERROR
    rig.motor.calls = []
    rig.run_ms(1)
    assert rig.motor.calls[0] == ("set_rpm", 0)


def test_irq_counters_stay_small_ints_on_32_bit_ports():
    import joint.core.controller as core
    import joint.core.irq as irq
    # A hard IRQ computes counter + 1 before masking: it must not reach 2**30 (a long int there).
    assert core.COUNTER_MASK + 1 <= 2 ** 30 - 1
    assert core.COUNTER_MASK % 16 == 15, "slot = counter % 16 must survive the wrap"
    rig = Rig()
    ftab = rig.core._ftab
    rig.core.transactions = core.COUNTER_MASK
    ftab[irq.FTAB_Q_IN] = ftab[irq.FTAB_Q_OUT] = 0xFF  # the queue's counters are bytes
    rig.command("SETCURRENT", 30)
    assert rig.core.transactions == 0 and ftab[irq.FTAB_Q_IN] == 0, "one transaction, wrapped"
    rig.run_ms(1)
    assert ("set_current", 30) in rig.motor.calls and ftab[irq.FTAB_Q_OUT] == 0


def test_a_full_queue_rejects_with_the_error_flag_and_drops_nothing_accepted():
    rig = Rig()
    rig.command("SETUP", 20, 20, 0, 0)
    accepted = []
    rejected = 0
    for i in range(20):
        flags = rig.command("MOVESTEPS", i)
        if flags & P.FLAG_ERROR:
            rejected += 1
        else:
            accepted.append(i)
    assert len(accepted) == 15 and rejected == 5, (accepted, rejected)
    assert rig.read("LASTERROR")[0][0] == P.REJECT_QUEUE_FULL
    rig.run_ms(1)
    assert [c[1] for c in rig.motor.calls if c[0] == "move_steps"][1:] == accepted
    assert not rig.command("MOVESTEPS", 99) & P.FLAG_ERROR, "room again after the main loop ran"


def test_motion_queued_before_a_stall_is_not_applied_after_it():
    rig = Rig()
    rig.command("SETUP", 20, 20, 0, 0)
    rig.run_ms(1)
    rig.command("SETRPM", 50.0)
    rig.core._halt(P.FLAG_STALL)  # the main loop found a stall before applying the queued command
    rig.motor.calls = []
    rig.run_ms(1)
    assert rig.motor.calls == []


def test_a_second_blocking_command_is_rejected_while_one_runs():
    rig = Rig()
    rig.command("SETUP", 20, 20, 0, 0)
    rig.command("HOME", 1, 10, 30, 15)
    assert rig.command("CHECKORIENTATION", 2.0) & P.FLAG_ERROR
    assert rig.read("LASTERROR")[0][0] == P.REJECT_BUSY
    rig.command("STOP", 0)
    assert rig.command("HOME", 1, 10, 30, 15) == P.FLAG_NOTHOMED | P.FLAG_BUSY, \
        "a STOP cancelled the first: a new HOME is accepted at once"
    rig.run_ms(600)
    assert rig.core.task_name == "HOME" and rig.core.flags & P.FLAG_BUSY, "and it runs"
    assert sum(1 for c in rig.motor.calls if c[0] == "set_rpm" and c[1] == 10) == 1


def test_a_stop_while_a_blocking_command_is_applied_cancels_it():
    """The main loop takes a HOME from the queue and starts its task; a STOP accepted in between
    (on the chip the cancelled task before it winds down for milliseconds: driver writes, a log
    line) cancels the new task, which belongs to the stop epoch its command was accepted in, and
    the next HOME is accepted."""
    rig = Rig()
    rig.command("SETUP", 20, 20, 0, 0)
    rig.command("HOME", 1, 10, 30, 15)
    rig.run_ms(600)
    rig.command("STOP", 0)
    assert not rig.command("HOME", 1, 10, 30, 15) & P.FLAG_ERROR
    wind_down = rig.core._finish_cancelled_task

    def stop_meanwhile():
        wind_down()
        assert not rig.command("STOP", 0) & P.FLAG_ERROR
    rig.core._finish_cancelled_task = stop_meanwhile
    rig.run_ms(1)
    assert rig.core.task_name == "HOME" and rig.core._cancelled(), "started, and cancelled by the STOP"
    assert not rig.command("HOME", 1, 10, 30, 15) & P.FLAG_ERROR, "no blocking command is live"


def _boundary_payloads(reg):
    """Payloads of `reg` at and just past every field's limits, non-finite floats, wrong lengths."""
    per_field = []
    for f in reg.write:
        if f.kind == P.F32:
            values = [struct.pack("<f", v) for v in (
                f.lo, f.hi, -f.lo, -f.hi, f.lo * 0.999, f.hi * 1.001, 0.0, float("inf"), float("nan"))]
            values.append(struct.pack("<I", 0x00000001))  # the smallest denormal
        elif f.kind == P.U16:
            values = [struct.pack("<H", v) for v in (f.lo, f.hi, min(f.hi + 1, 0xFFFF), 0xFFFF)]
        elif f.kind == P.I32:
            values = [struct.pack("<i", v) for v in (0, -1, 0x7FFFFFFF)]
        else:
            values = [bytes([v]) for v in (f.lo, f.hi, max(f.lo - 1, 0), min(f.hi + 1, 255))]
        per_field.append(values)
    good = b"".join(values[0] for values in per_field)
    payloads = [good, good[:-1], good + b"\x00", b""]
    for i, values in enumerate(per_field):
        for value in values:
            payloads.append(b"".join(value if j == i else per_field[j][0] for j in range(len(per_field))))
    return payloads


def test_the_irq_frame_checks_give_the_spec_verdict_for_every_register():
    """The IRQ path checks frames from tables built at boot: its reject reason for a malformed frame
    is the one Register.check_write gives, and a well-formed frame is never rejected as malformed."""
    rig = Rig()
    malformed = (P.REJECT_UNKNOWN_REGISTER, P.REJECT_UNSUPPORTED, P.REJECT_LENGTH, P.REJECT_VALUE)
    for addr in range(256):
        reg = P.BY_ADDR[addr]
        for payload in _boundary_payloads(reg) if reg is not None else (b"\x00",):
            if not payload and reg.readable:
                continue  # a register selected for reading
            before = rig.core.reject_count()
            flags = rig.xfer(bytes([addr]) + payload, 1)[0]
            expected = P.REJECT_UNKNOWN_REGISTER if reg is None else reg.check_write(payload, 0, len(payload))
            reason = rig.core.cached_reply(P.LASTERROR)[0] if rig.core.reject_count() != before else P.REJECT_NONE
            if expected != P.REJECT_NONE:
                assert reason == expected and flags & P.FLAG_ERROR, (addr, payload, reason, expected)
            else:
                assert reason not in malformed, (addr, payload, reason)
            rig.xfer(bytes([P.STOP, 0]), 1)  # cancels what was accepted, so the next frame is judged alone
            rig.run_ms(1)
    rig.assert_handler_alive()


def test_the_irq_code_reads_the_spec_and_the_frame_table_where_they_are():
    """irq.py's viper code keeps the spec's numbers and the frame table's offsets as its own
    constants (the board forgets protocol.py and irq_init.py after boot): they must be theirs."""
    if MICROPYTHON:
        return  # const() names with a leading underscore are no module attributes there
    from joint.core import irq, irq_init as T
    assert (irq._R_NONE, irq._R_UNKNOWN_REGISTER, irq._R_LENGTH, irq._R_VALUE, irq._R_BUSY,
            irq._R_QUEUE_FULL, irq._R_DISABLED, irq._R_NOT_ENABLED, irq._R_STALLED,
            irq._R_HOMING_SENSITIVITY) == (
        P.REJECT_NONE, P.REJECT_UNKNOWN_REGISTER, P.REJECT_LENGTH, P.REJECT_VALUE, P.REJECT_BUSY,
        P.REJECT_QUEUE_FULL, P.REJECT_DISABLED, P.REJECT_NOT_ENABLED, P.REJECT_STALLED,
        P.REJECT_HOMING_SENSITIVITY)
    assert (irq._FLAG_STALL, irq._FLAG_NOTENABLED, irq._FLAG_ERROR, irq.MOTION_BLOCKED) == (
        P.FLAG_STALL, P.FLAG_NOTENABLED, P.FLAG_ERROR, P.FLAG_STALL | P.FLAG_NOTENABLED)
    assert (irq._HOMEOFFSET, irq._STOP, irq._SETRPM, irq._LASTERROR) == (P.HOMEOFFSET, P.STOP, P.SETRPM, P.LASTERROR)
    assert (irq.SLOT_FLAGS, irq.SLOT) == (P.MAX_FRAME, P.MAX_FRAME + 3)
    assert (irq._REGISTERS, irq.REGISTER_SPACE, irq._PRE, irq._WLEN, irq.FTAB_WLEN, irq._CHECK, irq._SETS,
            irq._CLEARS, irq._ZERO_SETS, irq._BLOCKS, irq._REFUSE, irq._LO, irq._HI, irq._LIMITS) == (
        T.REGISTERS, T.REGISTERS, T.PRE, T.WLEN, T.WLEN, T.CHECK, T.SETS, T.CLEARS, T.ZERO_SETS, T.BLOCKS,
        T.REFUSE, T.LO, T.HI, T.LIMITS)
    assert (irq._DISABLED, irq.FTAB_DISABLED, irq._STOPS, irq._HALTS, irq.FTAB_HALTS, irq._MOTION, irq._HOMING) == (
        T.DISABLED, T.DISABLED, T.STOPS, T.HALTS, T.HALTS, T.MOTION, T.HOMING)
    assert (irq._CHECK_BYTES, irq._CHECK_F32, irq._CHECK_U16) == (T.CHECK_BYTES, T.CHECK_F32, T.CHECK_U16)
    assert (irq._BLOCK_IN, irq._BLOCK_OUT, irq.FTAB_BLOCK_OUT, irq._BLOCK_STOPS, irq._TASK, irq.FTAB_TASK,
            irq._TASK_STOPS, irq.FTAB_TASK_STOPS, irq._HOMING_FLOOR, irq._HOMING_FLOOR_Q) == (
        T.BLOCK_IN, T.BLOCK_OUT, T.BLOCK_OUT, T.BLOCK_STOPS, T.TASK, T.TASK, T.TASK_STOPS, T.TASK_STOPS,
        T.HOMING_FLOOR, T.HOMING_FLOOR_Q)
    assert (irq._LAST_REASON, irq._LAST_REGISTER, irq._REJECTS, irq.FTAB_REJECTS) == (
        T.LASTERROR_WIRE, T.LASTERROR_WIRE + 1, T.LASTERROR_WIRE + 2, T.LASTERROR_WIRE + 2)
    assert T.BLOCK_IN == T.HALTS + 1 and T.HOMING_FLOOR == T.TASK_STOPS + 1
    assert T.HOMING_FLOOR_Q == T.HOMING_FLOOR + 2 and T.LASTERROR_WIRE == T.HOMING_FLOOR_Q + 2
    assert T.Q_IN == T.LASTERROR_WIRE + P.register("LASTERROR").rsize + 1
    assert (irq._Q_IN, irq.FTAB_Q_IN, irq._Q_OUT, irq.FTAB_Q_OUT, irq._REARMS, irq.FTAB_REARMS) == (
        T.Q_IN, T.Q_IN, T.Q_OUT, T.Q_OUT, T.REARMS, T.REARMS)
    assert T.Q_OUT == T.Q_IN + 1 and T.REARMS == T.Q_OUT + 1 and T.SIZE == T.REARMS + 1
    assert 256 % irq.QUEUE_SLOTS == 0, "slot = byte counter % slots survives the wrap"
    assert T.REGISTERS * 4 <= T.HI - T.LO and T.LIMITS + T.REGISTERS * 8 <= T.DISABLED


class Rp2Events:
    """machine.I2CTarget as the rp2 driver drives a handler, one event at a time, with the bus
    activity bit under the test's control: for event orders the simulated bus never produces."""

    def __init__(self):
        self.event = 0
        self.rx = bytearray(16)
        self.rx_len = 0
        self.sent = bytearray()
        self.active = True
        self.handler = None

    def irq(self, handler=None, trigger=None, hard=False):
        self.handler = handler
        return self

    def flags(self):
        return self.event

    def readinto(self, buf):
        n = self.rx_len
        buf[:n] = self.rx[:n]
        self.rx_len = 0
        return n

    def write(self, buf):
        self.sent.extend(buf)
        return len(buf)

    def fire(self, event, data=b""):
        self.rx[:len(data)] = data
        self.rx_len = len(data)
        self.event = event
        self.handler(self)


def _rp2_rig():
    rig = Rig()
    target = Rp2Events()
    rig.adapter.deinit()
    adapter = I2CTargetAdapter(rig.core, True, lambda: target.active)
    adapter.attach(target)
    return rig, target, adapter


def test_a_command_the_rp2_driver_ends_early_is_kept_whole():
    """A STOP serviced after the next START and first byte makes the rp2 driver end that write
    early (chip/README.md): a short command frame while the bus is still active stays open."""
    rig, target, adapter = _rp2_rig()
    setup = bytearray([P.SETUP]) + P.register("SETUP").encode(20, 20, 0, 0)
    rig.core.on_frame(setup, len(setup))
    rig.run_ms(1)
    rejects = rig.core.reject_count()
    payload = P.register("SETRPM").encode(12.5)
    target.fire(WQ, bytes([P.SETRPM]))
    target.fire(E_W)  # the late STOP of the transaction before
    target.fire(WQ, payload)
    target.fire(E_W)  # the repeated START
    target.fire(RQ)
    target.fire(RQ)
    target.fire(E_R)
    assert rig.core.reject_count() == rejects and not target.sent[0] & P.FLAG_ERROR, target.sent
    rig.run_ms(1)
    assert ("set_rpm", 12.5) in rig.motor.calls


class Rp2Registers:
    """The RP2040 I2C block's registers as `ptr32(address)` sees them (CPython: viper takes an
    address there, the shim a buffer)."""

    def __init__(self, ptr32):
        self.words = {}
        self._ptr32 = ptr32

    def __call__(self, obj):
        if not isinstance(obj, int):
            return self._ptr32(obj)
        words = self.words

        class Word:
            def __getitem__(self, i):
                return words.get(obj, 0)

            def __setitem__(self, i, value):
                words[obj] = value
        return Word()


_I2C0 = 0x40044000  # the RP2040's I2C0 block


def _rp2_block_rig(make_target):
    """An enabled Rig whose adapter serves `make_target(registers)` and reaches the I2C0 block's
    registers through `registers` (Rp2Registers in place of the adapter's ptr32); returns (rig,
    target, registers, restore), `restore()` putting ptr32 back."""
    import joint.links.i2c_target as adapter_module
    rig = Rig()
    rig.command("SETUP", 20, 20, 0, 0)
    rig.run_ms(1)
    registers = Rp2Registers(adapter_module.ptr32)

    def restore():
        adapter_module.ptr32 = registers._ptr32

    adapter_module.ptr32 = registers
    try:
        rig.adapter.deinit()
        target = make_target(registers)
        I2CTargetAdapter(rig.core, True, lambda: target.active, _I2C0).attach(target)
    except BaseException:
        restore()
        raise
    return rig, target, registers, restore


def test_a_write_request_with_nothing_left_leaves_the_rx_threshold_alone():
    """rp2 handles a repeated START before the RX_FULL of the same interrupt: END_WRITE takes the
    command's last bytes and the WRITE_REQ after it finds none. The RX FIFO threshold stays the
    driver's, or the next read's register byte would raise no RX_FULL and the read would get the
    reply selected before."""
    if MICROPYTHON:
        return  # viper writes the address itself there; the chip suite runs this event order
    rig, target, registers, restore = _rp2_block_rig(lambda registers: Rp2Events())
    try:
        rx_tl = _I2C0 + 0x38
        target.fire(WQ, bytes([P.SETRPM]))
        assert registers.words[rx_tl] == 3, "RX_FULL again when the frame is whole"
        target.fire(E_W, P.register("SETRPM").encode(12.5))  # the repeated START, the rest with it
        assert registers.words[rx_tl] == 0
        target.fire(WQ)  # the same snapshot's RX_FULL
        assert registers.words[rx_tl] == 0, "the driver's threshold: RX_FULL with the next byte"
        target.fire(RQ)
        target.fire(E_R)
        assert not target.sent[0] & P.FLAG_ERROR
        target.fire(WQ, bytes([P.PING]))
        target.fire(E_W)
        target.fire(RQ)
        assert bytes(target.sent[1:3]) == b"O" + bytes([rig.core.flags]), target.sent
    finally:
        restore()


class LastByteLater(Rp2Events):
    """The rp2 driver as at 400 kHz: a call that takes a command's register byte ends while the
    command's last byte is still on the wire; the RX FIFO's level (IC_RXFLR) shows it once it landed."""

    def __init__(self, registers, rxflr):
        super().__init__()
        self.later = b""
        self._registers = registers
        self._rxflr = rxflr

    def readinto(self, buf):
        if self.rx_len:
            n = super().readinto(buf)
            self._registers.words[self._rxflr] = len(self.later)  # lands while the call runs
            return n
        n = len(self.later)
        buf[:n] = self.later
        self.later = b""
        self._registers.words[self._rxflr] = 0
        return n


def test_a_commands_last_byte_landing_during_the_call_before_it_is_taken_in_that_call():
    """A 2-byte command whose register byte's WRITE_REQ call sees the value byte land: the call
    waits for it and takes it (the RX FIFO's level says when), so no RX_FULL call is asked for
    the last byte (28 us of IRQ CPU on the chip) and the frame is whole at the repeated START."""
    if MICROPYTHON:
        return  # viper reads the address itself there; the chip bench measures this path
    rig, target, registers, restore = _rp2_block_rig(lambda registers: LastByteLater(registers, _I2C0 + 0x78))
    try:
        before = rig.core.reject_count()
        target.later = bytes([30])
        target.fire(WQ, bytes([P.SETCURRENT]))
        assert target.later == b"", "the value byte was taken in the register byte's call"
        assert registers.words[_I2C0 + 0x38] == 0, "no RX_FULL asked for: the frame is whole"
        target.fire(E_W)  # the repeated START
        target.fire(RQ)
        target.fire(E_R)
        assert not target.sent[0] & P.FLAG_ERROR and rig.core.reject_count() == before
        rig.run_ms(2)
        assert rig.core.drive_current == 30
    finally:
        restore()


def test_a_short_command_is_rejected_at_the_read_or_at_stop():
    rig, target, adapter = _rp2_rig()
    target.fire(WQ, bytes([P.SETRPM]))
    target.fire(E_W)  # repeated START: kept open while the bus is active ...
    target.fire(RQ)  # ... and judged when the read begins
    assert target.sent[0] & P.FLAG_ERROR
    assert rig.core.cached_reply(P.LASTERROR)[0] == P.REJECT_LENGTH
    target.fire(RQ)
    target.fire(E_R)
    target.active = False
    target.fire(WQ, bytes([P.SETRPM]))
    before = rig.core.reject_count()
    target.fire(E_W)  # STOP, bus idle: judged at once
    assert rig.core.reject_count() == before + 1


def test_the_main_loop_reads_the_queue_and_the_spec_where_they_are():
    """loop.py keeps the queue layout, the cache registers and the fixed-point formats it uses
    every iteration as its own constants: they must be theirs."""
    if MICROPYTHON:
        return  # const() names with a leading underscore are no module attributes there
    from joint.motion import fixed
    from joint.core import irq, loop
    assert (loop._ANGLE_Q, loop._RPM_Q) == (fixed.ANGLE_Q, fixed.RPM_Q)
    assert (loop._ANGLEMOVED, loop._GETENCODERRPM, loop._GETDRIVERRPM, loop._GETPIDERROR, loop._LASTERROR) == (
        P.ANGLEMOVED, P.GETENCODERRPM, P.GETDRIVERRPM, P.GETPIDERROR, P.LASTERROR)
    assert (loop._SLOT_MASK, loop._SLOT, loop._SLOT_FLAGS, loop._SLOT_HALTS, loop._SLOT_STOPS) == (
        irq.QUEUE_SLOTS - 1, irq.SLOT, irq.SLOT_FLAGS, irq.SLOT_HALTS, irq.SLOT_STOPS)
    assert loop._MOTION_BLOCKED == irq.MOTION_BLOCKED
    assert (loop._FTAB_BLOCK_OUT, loop._FTAB_REJECTS, loop._FTAB_Q_IN, loop._FTAB_Q_OUT) == (
        irq.FTAB_BLOCK_OUT, irq.FTAB_REJECTS, irq.FTAB_Q_IN, irq.FTAB_Q_OUT)
    assert irq.QUEUE_SLOTS & (irq.QUEUE_SLOTS - 1) == 0, "the slot mask needs a power of two"
