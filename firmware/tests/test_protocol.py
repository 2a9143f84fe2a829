"""The shared protocol spec: the original register map, byte layouts, validation and the spec hash."""

import struct

from joint.spec import protocol as P

# The original map as the original host puts it on the wire (original-host-behaviour.md 1.6):
# (address, name, write bytes, read payload bytes, blocking).
ORIGINAL_USED = (
    (0x0F, "PING", 0, 1, False),
    (0x10, "SETUP", 4, 0, False),
    (0x11, "SETRPM", 4, 0, False),
    (0x13, "MOVESTEPS", 4, 0, False),
    (0x15, "MOVETOANGLE", 4, 0, False),
    (0x18, "ANGLEMOVED", 0, 4, False),
    (0x19, "SETCURRENT", 1, 0, False),
    (0x1A, "SETHOLDCURRENT", 1, 0, False),
    (0x1B, "SETMAXACCELERATION", 4, 0, False),
    (0x1D, "SETMAXVELOCITY", 4, 0, False),
    (0x1E, "ENABLESTALLGUARD", 1, 0, False),
    (0x22, "SETBRAKEMODE", 1, 0, False),
    (0x26, "DISABLECLOSEDLOOP", 1, 0, False),
    (0x29, "STOP", 1, 0, False),
    (0x2B, "CHECKORIENTATION", 4, 0, True),
    (0x2C, "GETENCODERRPM", 0, 4, False),
    (0x2D, "HOME", 4, 0, True),
    (0x2E, "HOMEOFFSET", 4, 4, False),
)
ORIGINAL_ENUM = (
    "PING", "SETUP", "SETRPM", "GETDRIVERRPM", "MOVESTEPS", "MOVEANGLE", "MOVETOANGLE",
    "GETMOTORSTATE", "RUNCOTINOUS", "ANGLEMOVED", "SETCURRENT", "SETHOLDCURRENT",
    "SETMAXACCELERATION", "SETMAXDECELERATION", "SETMAXVELOCITY", "ENABLESTALLGUARD",
    "DISABLESTALLGUARD", "CLEARSTALL", None, "SETBRAKEMODE", "ENABLEPID", "DISABLEPID",
    "ENABLECLOSEDLOOP", "DISABLECLOSEDLOOP", "SETCONTROLTHRESHOLD", "MOVETOEND", "STOP",
    "GETPIDERROR", "CHECKORIENTATION", "GETENCODERRPM", "HOME", "HOMEOFFSET",
)


def test_every_original_register_is_declared_at_its_address():
    for offset, name in enumerate(ORIGINAL_ENUM):
        addr = 0x0F + offset
        reg = P.BY_ADDR[addr]
        if name is None:
            assert reg is None, "0x21 is not in the original enum"
        else:
            assert reg is not None and reg.name == name, (hex(addr), name)


def test_registers_the_original_host_uses_have_its_layout():
    for addr, name, wsize, rsize, blocking in ORIGINAL_USED:
        reg = P.register(name)
        assert reg.addr == addr
        assert reg.supported
        assert reg.wsize == wsize, name
        assert reg.rsize == rsize, name
        assert reg.blocking == blocking, name


def test_setup_payload_is_drive_hold_zero_zero():
    # The original host sends uint32 drive | hold << 8, little-endian.
    assert P.register("SETUP").encode(20, 40, 0, 0) == struct.pack("<I", 20 | 40 << 8)
    assert P.register("SETUP").encode(20, 40, 0, 0) == bytes([20, 40, 0, 0])


def test_home_payload_is_direction_speed_sensitivity_current():
    payload = P.register("HOME").encode(0, 45, 50, 30)
    assert payload == struct.pack("<I", 0 | 45 << 8 | 50 << 16 | 30 << 24)


def test_float_and_int_payloads_are_little_endian_binary32_and_int32():
    assert P.register("SETRPM").encode(-12.5) == struct.pack("<f", -12.5)
    assert P.register("MOVESTEPS").encode(-51200) == struct.pack("<i", -51200)
    assert P.register("ANGLEMOVED").decode(struct.pack("<f", 90.0)) == (90.0,)


def test_flag_bits_ack_and_boot_flags():
    assert (P.FLAG_STALL, P.FLAG_BUSY, P.FLAG_NOTHOMED, P.FLAG_NOTENABLED) == (1, 2, 4, 8)
    assert P.FLAG_ERROR == 0x10, "ERROR lives in the first reserved bit"
    assert P.FLAGS_AT_BOOT == 0x0C
    assert P.ACK == ord("O")
    assert P.describe_flags(0x0C) == "NOTHOMED|NOTENABLED"
    assert P.describe_flags(0) == "-"


def test_error_codes_and_strings():
    assert P.ERR_INVALID_ARGUMENT == -101 and P.ERR_INCORRECT_STATE == -109
    assert P.error_string(P.ERR_COMM_ERROR) == "communication error"
    assert P.error_string(-7) == "unknown (-7)"
    assert len(set(code for code, _, _ in P.ERROR_CODES)) == len(P.ERROR_CODES)


def test_immediate_flag_effects_match_the_original():
    assert P.register("SETUP").clears == P.FLAG_NOTENABLED | P.FLAG_STALL
    assert P.register("STOP").clears == P.FLAG_BUSY
    assert P.register("HOME").sets == P.FLAG_NOTHOMED | P.FLAG_BUSY
    assert P.register("CHECKORIENTATION").sets == P.FLAG_BUSY
    assert P.register("SETCURRENT").zero_sets == P.FLAG_NOTENABLED
    assert P.register("SETHOLDCURRENT").zero_sets == P.FLAG_NOTENABLED
    assert P.register("DISABLECLOSEDLOOP").sets == P.FLAG_NOTENABLED
    assert P.register("ENABLESTALLGUARD").clears == P.FLAG_STALL


def test_payload_check_rejects_non_finite_and_out_of_range_floats():
    reg = P.register("SETRPM")
    for value, reason in ((100.0, P.REJECT_NONE), (-5000.0, P.REJECT_NONE), (5000.5, P.REJECT_VALUE),
                          (float("nan"), P.REJECT_VALUE), (float("inf"), P.REJECT_VALUE),
                          (float("-inf"), P.REJECT_VALUE), (0.0, P.REJECT_NONE), (-0.0, P.REJECT_NONE)):
        assert reg.check_write(struct.pack("<f", value), 0, 4) == reason, value
    accel = P.register("SETMAXACCELERATION")
    assert accel.check_write(struct.pack("<f", 0.0), 0, 4) == P.REJECT_VALUE, "zero acceleration never moves"
    assert accel.check_write(struct.pack("<f", -18000.0), 0, 4) == P.REJECT_NONE, "the original host sends J2 negative"


def test_payload_check_rejects_wrong_lengths_and_u8_ranges():
    setup = P.register("SETUP")
    assert setup.check_write(bytes([20, 20, 0, 0]), 0, 4) == P.REJECT_NONE
    assert setup.check_write(bytes([101, 20, 0, 0]), 0, 4) == P.REJECT_VALUE
    assert setup.check_write(bytes([20, 20, 0, 1]), 0, 4) == P.REJECT_VALUE
    assert setup.check_write(bytes([20, 20]), 0, 2) == P.REJECT_LENGTH
    assert P.register("PING").check_write(b"\x00", 0, 1) == P.REJECT_LENGTH
    assert P.register("GETMOTORSTATE").check_write(b"\x00", 0, 1) == P.REJECT_UNSUPPORTED
    assert P.register("HOME").check_write(bytes([2, 10, 10, 10]), 0, 4) == P.REJECT_VALUE
    assert P.register("HOME").check_write(bytes([1, 0, 10, 10]), 0, 4) == P.REJECT_VALUE


def test_encode_names_the_field_and_range():
    try:
        P.register("SETCURRENT").encode(150)
    except ValueError as exc:
        assert "drive_current" in str(exc) and "0..100" in str(exc)
    else:
        assert False, "150 % was accepted"
    try:
        P.register("SETRPM").encode(float("nan"))
    except ValueError as exc:
        assert "rpm" in str(exc)
    else:
        assert False, "NaN was accepted"


def test_wire_time_of_the_original_transactions():
    assert P.wire_bits(1, 5) == 75, "register read of a float"
    assert P.wire_bits(5, 1) == 75, "command with a 4-byte payload"
    assert P.wire_bits(0, 0) == 11, "address probe"


def _copy(reg, **changes):
    args = dict(addr=reg.addr, name=reg.name, write=reg.write, read=reg.read, blocking=reg.blocking,
                sets=reg.sets, clears=reg.clears, zero_sets=reg.zero_sets, supported=reg.supported)
    for key in changes:
        args[key] = changes[key]
    return P.Register(args["addr"], args["name"], args["write"], args["read"], args["blocking"],
                      args["sets"], args["clears"], args["zero_sets"], args["supported"])


def test_spec_hash_changes_when_any_register_definition_changes():
    assert P.spec_hash() == P.SPEC_HASH
    assert P.spec_hash(P.REGISTERS) == P.spec_hash(tuple(_copy(r) for r in P.REGISTERS))
    index = [r.name for r in P.REGISTERS].index("SETRPM")
    rpm = P.REGISTERS[index]
    wider = (P.Field("rpm", P.F32, "rpm (motor)", 0.0, 6000.0),)
    variants = (
        _copy(rpm, write=wider),
        _copy(rpm, blocking=True),
        _copy(rpm, addr=0x40),
        _copy(rpm, name="SETSPEED"),
        _copy(rpm, clears=P.FLAG_BUSY),
        _copy(rpm, write=(P.Field("rpm", P.F32, "rad/s", 0.0, 5000.0),)),
        _copy(rpm, write=(P.Field("rpm", P.I32, "rpm (motor)"),)),
    )
    seen = {P.SPEC_HASH}
    for variant in variants:
        table = P.REGISTERS[:index] + (variant,) + P.REGISTERS[index + 1:]
        digest = P.spec_hash(table)
        assert digest not in seen, variant.name
        seen.add(digest)


def test_angles_the_joint_cannot_carry_exactly_are_refused_not_clamped():
    """MOVEANGLE / MOVETOANGLE travel as Q12 degrees: beyond the spec's limit a frame is an ERROR
    (issue 20: +-262,144 degrees and more used to be accepted and clamped)."""
    for name in ("MOVEANGLE", "MOVETOANGLE"):
        field = P.register(name).write[0]
        assert field.hi * 2 * (1 << 12) < (1 << 30), "the limit plus a homing offset of as much fits Q12"
        for value, ok in ((field.hi, True), (-field.hi, True), (262144.0, False), (-1e6, False)):
            buf = bytearray(struct.pack("<f", value))
            assert field.check(buf, 0) == ok, (name, value)


def test_the_bitwise_crc32_is_zlibs():
    # The S32 image has no binascii.crc32: protocol.crc32_bitwise computes the spec hash there.
    assert P.crc32_bitwise(b"123456789") == 0xCBF43926  # the CRC-32 check value
    assert P.crc32_bitwise(b"") == 0
    data = bytes(range(256)) * 3
    assert P.crc32_bitwise(data) == P.crc32(data) & 0xFFFFFFFF, "the port's own crc32 where it has one"
    assert P.crc32_bitwise(data[300:], P.crc32_bitwise(data[:300])) == P.crc32_bitwise(data), "it continues"
