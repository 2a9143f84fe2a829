"""Protocol v2 on the joint: the memory map served by the mem-mode target, the switch between the
two maps, every rejection path, whole-block reads, and an allocation-free main loop."""

from joint.spec import protocol as P, protocol_v2 as V
from joint.sim.i2c_target import FakeI2CTarget
from joint.motion.fixed import f32_to_q, rescale, store_q
from joint.links.memmap_v2 import _mailbox_crc, _state_crc

from v2rig import V2Rig


def test_crc8_smbus_matches_the_catalogue_and_the_smbus_pec_vectors():
    assert V.crc8(b"123456789", 0, 9) == 0xF4
    assert V.crc8(bytes((0xB4, 0x06, 0xAB, 0xCD)), 0, 4) == 0x5F
    assert V.crc8(bytes((0xB4, 0x06, 0xB5, 0x26, 0x3A)), 0, 5) == 0x66
    assert V.crc8(bytes((0x84, 0x10, 0x85, 0x55)), 0, 4) == 0x90
    assert V.crc8_byte(0x01) == 0x07 and V.crc8_byte(0xFF) == 0xF3


def test_the_joints_own_crc_loops_agree_with_the_spec():
    # v2.py keeps its own loops because protocol_v2 is dropped after boot on the board.
    for seed in range(1, 64):
        buf = bytes((seed * 37 + 11 * i) & 0xFF for i in range(max(V.MAILBOX_SIZE, V.STATE_SIZE)))
        for address in (0x11, 0x12, 0x13, 0x14, seed & 0x7F):
            assert _mailbox_crc(buf, address) == V.mailbox_crc(buf, 0, address)
            assert _state_crc(buf, address) == V.state_crc(buf, 0, address)


def test_the_layout_fits_one_combined_transaction_of_156_bit_times():
    assert V.MAILBOX + V.MAILBOX_SIZE == V.STATE and V.STATE + V.STATE_SIZE == V.MEM_SIZE
    assert P.wire_bits(V.MAILBOX_SIZE, V.STATE_SIZE) == V.TRANSACTION_BITS == 156
    assert 4 * V.TRANSACTION_BITS <= 630
    assert 4 * 3 * P.wire_bits(5, 1) == 900  # legacy: a command and two register reads per joint


def test_the_state_block_rescales_the_cached_integers_as_the_float32_caches_did():
    """Position and velocity come from the integers behind the ANGLEMOVED / GETENCODERRPM caches
    (Q12 degrees, Q16 rpm), rounded half away from zero and saturated: the same numbers the
    float32 caches gave wherever float32 holds the integer exactly (|value| < 2**24)."""
    def via_float32(value, q, shift, limit):
        cache = bytearray(4)
        store_q(cache, value, q)
        return max(-limit, min(limit, f32_to_q(cache, 0, q - shift)))
    values = [0, 1, -1, 31, 32, 33, -32, -33, 95, 96, -96, 4096 * 359, -12211 * 4096 - 2048,
              (1 << 24) - 1, -(1 << 24) + 1]
    for value in values:
        expected = (abs(value) * 2 + 64) // 128 * (-1 if value < 0 else 1)
        assert rescale(value, 6, V.POSITION_MAX) == expected == via_float32(value, 12, 6, V.POSITION_MAX), value
        assert rescale(value, 13, V.VELOCITY_MAX) == via_float32(value, 16, 13, V.VELOCITY_MAX), value
    assert rescale((1 << 30) - 1, 6, V.POSITION_MAX) == V.POSITION_MAX
    assert rescale(-(1 << 30) + 1, 6, V.POSITION_MAX) == -V.POSITION_MAX
    assert rescale(5000 << 16, 13, V.VELOCITY_MAX) == V.VELOCITY_MAX
    assert rescale(-5000 << 16, 13, V.VELOCITY_MAX) == -V.VELOCITY_MAX


def test_a_fresh_joint_serves_legacy_and_switches_to_v2_and_back():
    rig = V2Rig()
    assert rig.switch.protocol == V.PROTOCOL_LEGACY
    assert rig.xfer(bytes([P.PING]), 2) == b"O\x0c"
    rig.to_v2()
    flags, verdict, _, _, _ = rig.state()
    assert flags == P.FLAGS_AT_BOOT and verdict == V.REASON_OK
    assert rig.command("PROTOCOL", 1) == (V.REASON_OK, P.FLAGS_AT_BOOT)
    rig.tick()
    assert rig.switch.protocol == V.PROTOCOL_LEGACY
    assert rig.xfer(bytes([P.PING]), 2) == b"O\x0c", "legacy again, without a power cycle"


class OrderRig(V2Rig):
    """Records when the legacy adapter's tables are built and when a target starts answering."""

    def __init__(self):
        self.events = []
        V2Rig.__init__(self)

    def _make_target(self, mem):
        self.events.append("target")
        return V2Rig._make_target(self, mem)

    def _legacy(self):
        self.events.append("tables")
        return V2Rig._legacy(self)


def test_a_legacy_target_is_created_only_once_its_tables_are_built():
    """A target acknowledges its address from its creation on, and a read gets zeros until the
    handler is set: the adapter's tables (their allocation can start a collection, tens of ms on
    the chip) come first. The emulated chip answered PING 00 00 right after its first ACK."""
    rig = OrderRig()
    assert rig.events == ["tables", "target"]
    rig.to_v2()
    rig.command("PROTOCOL", 1)
    rig.tick()
    assert rig.switch.protocol == V.PROTOCOL_LEGACY
    assert rig.events == ["tables", "target", "target", "tables", "target"]
    assert rig.xfer(bytes([P.PING]), 2) == b"O\x0c"


def test_host_silence_returns_a_v2_joint_to_legacy():
    rig = V2Rig()
    rig.to_v2()
    rig.state()
    rig.run_ms(V.SILENCE_MS - 5)
    assert rig.switch.protocol == V.PROTOCOL_V2
    rig.run_ms(10)
    assert rig.switch.protocol == V.PROTOCOL_LEGACY
    assert any("serving the legacy map" in line for line in rig.lines)


def test_commands_are_applied_through_the_shared_core_with_the_legacy_checks():
    rig = V2Rig()
    rig.to_v2()
    verdict, flags = rig.command("SETUP", 60, 30, 0, 0)
    assert verdict == V.REASON_OK and not flags & P.FLAG_NOTENABLED
    assert ("set_current", 60) in rig.motor.calls and ("set_hold_current", 30) in rig.motor.calls
    rig.motor.calls = []
    assert rig.command("MOVESTEPS", 1234)[0] == V.REASON_OK
    assert rig.motor.calls == [("move_steps", 1234)]
    rig.motor.angle = -12.5
    rig.motor.rpm = 100.25
    for _ in range(4):  # the speed caches refresh one per iteration in turn
        rig.tick()
    flags, _, position, velocity, _ = rig.state()
    assert position == -800 and velocity == 802


def test_invalid_values_unknown_commands_and_busy_are_rejected_and_reported():
    rig = V2Rig()
    rig.to_v2()
    rig.command("SETUP", 60, 30, 0, 0)
    rig.motor.calls = []
    bad = bytearray(rig.frame("SETUP", 60, 30, 0, 0))
    bad[1] = 101  # drive current above 100 %
    bad[V.M_CRC] = V.mailbox_crc(bad, 0, rig.address)
    rig.exchange(bytes(bad))
    assert V.decode_state(rig.address, rig.xfer(rig.frame(), 8))[1] == V.REASON_VALUE
    rig.tick()
    for cmd in (0x01, P.IDENTITY, P.GETMOTORSTATE):
        raw = V.encode_frame(rig.address, cmd, b"", rig.frame()[V.M_SEQ])
        rig.exchange(raw)
        assert V.decode_state(rig.address, rig.xfer(rig.frame(), 8))[1] == V.REASON_COMMAND
        rig.tick()
    padded = bytearray(rig.frame("SETCURRENT", 50))
    padded[2] = 7  # padding after the 1-byte payload must be zero
    padded[V.M_CRC] = V.mailbox_crc(padded, 0, rig.address)
    rig.exchange(bytes(padded))
    assert V.decode_state(rig.address, rig.xfer(rig.frame(), 8))[1] == V.REASON_VALUE
    rig.tick()
    assert rig.motor.names().count("set_current") == 0  # no rejected SETUP or SETCURRENT reached the motor
    assert rig.command("HOME", 1, 10, 50, 40)[0] == V.REASON_OK  # (homing energizes the motor itself)
    assert rig.command("HOME", 1, 10, 50, 40)[0] == V.REASON_BUSY
    assert rig.link.rejected == 6


def ack_of(rig):
    """A poll that is a retry of the last accepted frame: judged without changing the verdict."""
    return rig.link.ack


def test_link_corruptions_are_never_applied_and_are_reported_and_counted():
    rig = V2Rig()
    rig.to_v2()
    rig.command("SETUP", 60, 30, 0, 0)
    rig.motor.calls = []
    good = rig.frame("MOVESTEPS", 100)
    flipped = bytearray(good)
    flipped[2] ^= 0x10
    cases = (
        (bytes(flipped), V.REASON_CRC),
        (good[:5], V.REASON_FRAME),  # truncated: the sequence byte never arrived
        (good + b"\x00", V.REASON_FRAME),  # one byte too many: it landed on the state block
    )
    for raw, reason in cases:
        rig.exchange(raw)
        flags, verdict, _, _, ack = V.decode_state(rig.address, rig.xfer(rig.frame(seq=ack_of(rig)), 8))
        rig.tick()
        assert verdict == reason, (raw, verdict)
    assert rig.motor.calls == [] and rig.link.crc_errors == 1 and rig.link.frame_errors == 2
    retries = rig.link.retries
    rig.exchange(good)  # now intact: applied
    rig.exchange(good)  # the same frame again (a retry): ignored, verdict unchanged
    state = V.decode_state(rig.address, rig.xfer(rig.frame(), 8))
    assert state[1] == V.REASON_OK and state[4] == good[V.M_SEQ]
    assert rig.motor.calls == [("move_steps", 100)] and rig.link.retries == retries + 1
    rig.tick()
    rig.exchange(good)  # replayed later: stale
    assert V.decode_state(rig.address, rig.xfer(rig.frame(), 8))[1] == V.REASON_SEQUENCE
    assert rig.motor.calls == [("move_steps", 100)]


def test_a_frame_for_another_joint_fails_its_crc():
    rig = V2Rig()
    rig.to_v2()
    rig.command("SETUP", 60, 30, 0, 0)
    rig.motor.calls = []
    elsewhere = V.encode_frame(rig.address ^ 0x01, P.MOVESTEPS, P.register("MOVESTEPS").encode(5),
                               rig.seq + 1)
    rig.exchange(elsewhere)
    assert rig.motor.calls == [] and rig.link.crc_errors == 1


def test_a_read_never_sees_a_half_written_block():
    rig = V2Rig()
    rig.to_v2()
    rig.state()
    target = rig.switch.target
    ticks = [0]

    def main_loop_between_bytes():
        rig.motor.angle += 1.0  # a new state every pass
        rig.tick()
        ticks[0] += 1
    target.on_wire = main_loop_between_bytes
    deferred = rig.link.deferred
    for _ in range(20):
        state = V.decode_state(rig.address, rig.xfer(rig.frame(), V.STATE_SIZE))
        assert state is not None, "torn block"
    target.on_wire = None
    assert ticks[0] > 0 and rig.link.deferred > deferred
    rig.tick()
    assert V.decode_state(rig.address, rig.xfer(rig.frame(), 8))[2] == int(rig.motor.angle) * 64


def test_interrupts_stay_on_while_a_transaction_is_in_progress():
    """rp2 handles a repeated START before the RX data that came with it: an I2C interrupt held
    off across the end of a write phase stores the late mailbox bytes at offset 0 and shifts the
    read (chip/README.md). The v2 joint, moving, with its main loop running between the bytes of
    every transaction, disables interrupts only while the bus is idle."""
    seen = {"rig": None, "off": 0, "mid_transaction": 0}

    def off():
        rig = seen["rig"]
        if rig is not None and rig.switch is not None:
            seen["off"] += 1
            if rig.switch.target.active:
                seen["mid_transaction"] += 1
        return 0

    def on(state):
        pass

    rig = V2Rig(critical=(off, on))
    seen["rig"] = rig
    rig.to_v2()
    rig.command("SETUP", 60, 30, 0, 0)
    assert rig.command("SETRPM", 10.0)[0] == V.REASON_OK
    target = rig.switch.target

    def main_loop_between_bytes():
        rig.motor.angle += 0.5  # the reply caches change every pass
        rig.tick()
    target.on_wire = main_loop_between_bytes
    before = seen["off"]
    for _ in range(10):
        assert V.decode_state(rig.address, rig.exchange(rig.frame())) is not None
    target.on_wire = None
    assert seen["off"] > before, "the swap's critical section ran"
    assert seen["mid_transaction"] == 0


def test_the_switch_back_to_legacy_waits_for_the_end_of_the_verdict_read():
    """The END_WRITE of the transaction after PROTOCOL 1 comes at its repeated START; the joint
    re-creates its target only after the STOP, so that read returns the whole verdict."""
    rig = V2Rig()
    rig.to_v2()
    rig.state()
    legacy = rig.frame("PROTOCOL", V.PROTOCOL_LEGACY)
    rig.exchange(legacy)
    target = rig.switch.target
    passes = [0]

    def main_loop_between_bytes():
        rig.tick()
        passes[0] += 1
    target.on_wire = main_loop_between_bytes
    state = V.decode_state(rig.address, rig.xfer(legacy, V.STATE_SIZE))
    target.on_wire = None
    assert passes[0] > 0 and rig.switch.protocol == V.PROTOCOL_V2
    assert state is not None and state[1] == V.REASON_OK and state[-1] == rig.seq
    rig.tick()
    assert rig.switch.protocol == V.PROTOCOL_LEGACY
    assert rig.xfer(bytes([P.PING]), 2) == b"O\x0c"


def test_the_main_loop_pass_allocates_nothing():
    rig = V2Rig()
    rig.to_v2()
    rig.command("SETUP", 60, 30, 0, 0)
    frames = [rig.frame("SETRPM", 10.0), rig.frame(), rig.frame("MOVESTEPS", 3), rig.frame()]
    target = rig.switch.target
    for raw in frames:
        target.transfer(raw, V.STATE_SIZE)
        rig.service_heap_locked()
    assert rig.link.applied >= 3 and rig.link.crc_errors == 0


def test_memory_mode_follows_micropython():
    mem = bytearray(b"01234567")
    target = FakeI2CTarget(0x42, mem=mem)
    target.transfer(bytes([6]) + b"test", 0)
    assert mem == bytearray(b"st2345te")
    mem[:] = b"01234567"
    assert target.transfer(bytes([0]), 12) == b"012345670123"
    assert target.transfer(bytes([2]), 4) == b"2345"
    assert target.transfer(None, 4) == b"7012", "the prefetch skips a byte"
    events = []
    target.irq(lambda t: events.append((t.flags(), t.memaddr)), trigger=16 | 32)
    target.transfer(bytes([3]), 2)
    target.transfer(bytes([5, 1, 2]), 0)
    assert events == [(16, 3), (32, 5)], "no END_WRITE for a write that only set the address"
    flat = FakeI2CTarget(0x42, mem=bytearray(range(15)), mem_addrsize=0)
    assert flat.transfer(bytes(7), 8) == bytes(range(7, 15)), "addrsize 0: write at 0, read after it"


def _mixed_with_a_valid_crc(rig, first):
    """A 3-byte write that, landing on `first` still in the mailbox, leaves a MOVESTEPS frame
    whose CRC-8 (first's, unchanged) is valid: what two writes in one loop pass could apply."""
    for b1 in range(256):
        for b2 in range(256):
            mixed = bytes([P.MOVESTEPS, b1, b2]) + first[3:]
            if V.mailbox_crc(mixed, 0, rig.address) == mixed[V.M_CRC]:
                return mixed[:3]
    raise AssertionError("no mix with a valid CRC")


def test_two_writes_in_one_loop_pass_are_never_applied_as_one_frame():
    rig = V2Rig()
    rig.to_v2()
    rig.command("SETUP", 60, 30, 0, 0)
    rig.motor.calls = []
    first = rig.frame("MOVESTEPS", 100)
    rig.xfer(first, 0)
    rig.xfer(_mixed_with_a_valid_crc(rig, first), 0)  # before the main loop took the first
    rig.tick()
    flags, verdict, _, _, _ = V.decode_state(rig.address, rig.xfer(rig.frame(seq=rig.link.ack), V.STATE_SIZE))
    rig.tick()
    assert verdict == V.REASON_FRAME and rig.motor.calls == [] and rig.link.frame_errors == 1
    rig.exchange(first)  # the host's retry: one write, applied once
    rig.exchange(first)
    assert rig.motor.calls == [("move_steps", 100)]


def test_a_frame_whose_end_of_write_is_not_yet_counted_waits_for_it():
    rig = V2Rig()
    rig.to_v2()
    rig.command("SETUP", 60, 30, 0, 0)
    rig.motor.calls = []
    handler = rig.switch.target._handler
    rig.switch.target._handler = None  # the soft END_WRITE callback has not run yet
    rig.xfer(rig.frame("MOVESTEPS", 7), 0)
    rig.tick()
    assert rig.motor.calls == [] and rig.link.frame_errors == 0
    rig.switch.target._handler = handler
    rig.link._count_write(rig.switch.target)  # now it runs
    rig.run_ms(2)  # judged, then run by the core's next pass
    assert rig.motor.calls == [("move_steps", 7)] and rig.link.frame_errors == 0
