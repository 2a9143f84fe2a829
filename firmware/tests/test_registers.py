"""Table-driven: every register's effect, exact reply bytes and motor commands, against the original."""

import struct

from joint.spec import protocol as P
from harness import Rig

ENABLED = 0x04  # after SETUP: homed bit still clear only after homing
OFF = 0x0C  # boot flags: not homed, not enabled

# (register, values, enable first, expected reply flags, expected motor calls after one main-loop pass)
COMMANDS = (
    ("SETUP", (20, 30, 0, 0), False, ENABLED,
     [("set_current", 20), ("set_hold_current", 30), ("move_steps", 0)]),
    ("SETRPM", (12.5,), True, ENABLED, [("set_rpm", 12.5)]),
    ("SETRPM", (12.5,), False, OFF | P.FLAG_ERROR, []),  # refused: not enabled
    ("SETRPM", (0.0,), False, OFF, [("set_rpm", 0.0)]),
    ("MOVESTEPS", (-51200,), True, ENABLED, [("move_steps", -51200)]),
    ("MOVESTEPS", (100,), False, OFF | P.FLAG_ERROR, []),
    ("MOVEANGLE", (-5.0,), True, ENABLED, [("move_angle", -5.0)]),
    ("MOVETOANGLE", (90.0,), True, ENABLED, [("move_to_angle", 90.0)]),
    ("MOVETOANGLE", (90.0,), False, OFF | P.FLAG_ERROR, []),
    ("SETCURRENT", (30,), True, ENABLED, [("set_current", 30)]),
    ("SETCURRENT", (0,), True, ENABLED | P.FLAG_NOTENABLED, [("set_current", 0)]),
    ("SETHOLDCURRENT", (25,), True, ENABLED, [("set_hold_current", 25)]),
    ("SETHOLDCURRENT", (0,), True, ENABLED | P.FLAG_NOTENABLED, [("set_hold_current", 0)]),
    ("SETMAXACCELERATION", (360.0,), False, OFF,
     [("set_max_acceleration", 200.0), ("set_max_deceleration", 200.0)]),
    ("SETMAXACCELERATION", (-18000.0,), False, OFF,
     [("set_max_acceleration", 10000.0), ("set_max_deceleration", 10000.0)]),
    ("SETMAXDECELERATION", (360.0,), False, OFF, [("set_max_deceleration", 200.0)]),
    ("SETMAXVELOCITY", (-2700.0,), False, OFF, [("set_max_velocity", 1500.0)]),
    ("ENABLESTALLGUARD", (6,), True, ENABLED, []),
    ("DISABLESTALLGUARD", (0,), True, ENABLED, []),
    ("CLEARSTALL", (0,), True, ENABLED, []),
    ("SETBRAKEMODE", (2,), False, OFF, [("set_brake_mode", 2)]),
    ("ENABLECLOSEDLOOP", (0,), False, OFF, [("enable_closed_loop",)]),
    ("DISABLECLOSEDLOOP", (0,), True, ENABLED | P.FLAG_NOTENABLED, [("disable_closed_loop",)]),
    ("STOP", (0,), True, ENABLED, [("set_rpm", 0)]),
)


def _close(a, b):
    if isinstance(a, float) or isinstance(b, float):
        return abs(a - b) < 1e-3
    return a == b


def _same_calls(got, want):
    return len(got) == len(want) and all(
        len(g) == len(w) and g[0] == w[0] and all(_close(x, y) for x, y in zip(g[1:], w[1:]))
        for g, w in zip(got, want))


def _enable(rig):
    rig.command("SETUP", 20, 20, 0, 0)
    rig.run_ms(1)
    rig.motor.calls = []


def test_every_command_reply_and_motor_effect():
    for name, values, enable, flags, calls in COMMANDS:
        rig = Rig()
        if enable:
            _enable(rig)
        reply = rig.command(name, *values)
        assert reply == flags, "%s%r replied 0x%02x, expected 0x%02x" % (name, values, reply, flags)
        rig.run_ms(1)
        assert _same_calls(rig.motor.calls, calls), "%s%r -> %r" % (name, values, rig.motor.calls)
        rig.assert_handler_alive()


def test_ping_replies_ack_and_flags():
    rig = Rig()
    assert rig.xfer(bytes([P.PING]), 2) == bytes([ord("O"), OFF])


def test_reads_return_values_the_main_loop_packed():
    rig = Rig()
    rig.motor.angle, rig.motor.rpm, rig.motor.ramp_rpm, rig.motor.error = 12.5, -3.25, 7.0, 42.0
    rig.run_ms(1)
    assert rig.xfer(bytes([P.ANGLEMOVED]), 5) == struct.pack("<f", 12.5) + bytes([OFF]), "every ms"
    rig.run_ms(1)
    assert rig.xfer(bytes([P.GETENCODERRPM]), 5) == struct.pack("<f", -3.25) + bytes([OFF]), "every 2 ms"
    rig.run_ms(2)  # the driver speed and the PID error: every fourth iteration each
    for name, value in (("ANGLEMOVED", 12.5), ("GETENCODERRPM", -3.25), ("GETDRIVERRPM", 7.0),
                        ("GETPIDERROR", 42.0)):
        reply = rig.xfer(bytes([P.register(name).addr]), 5)
        assert reply == struct.pack("<f", value) + bytes([OFF]), name


def test_setup_clears_stall_and_disables_stall_guard():
    rig = Rig()
    _enable(rig)
    rig.command("ENABLESTALLGUARD", 6)
    rig.run_ms(1)
    assert rig.core.stallguard and rig.core.stall.sensitivity == 6
    rig.core.flags |= P.FLAG_STALL
    assert rig.command("SETUP", 20, 20, 0, 0) == ENABLED, "SETUP clears STALL in its own reply"
    rig.run_ms(1)
    assert not rig.core.stallguard, "SETUP turns stall detection off, as the original"
    assert rig.core.qd_set == 0.0


def test_enable_stall_guard_clears_stall_and_motion_resumes():
    rig = Rig()
    _enable(rig)
    rig.core.flags |= P.FLAG_STALL
    assert rig.command("SETRPM", 10.0) == ENABLED | P.FLAG_STALL | P.FLAG_ERROR
    rig.run_ms(1)
    assert rig.motor.calls == [], "motion is ignored while stalled"
    assert rig.command("ENABLESTALLGUARD", 6) == ENABLED
    rig.command("SETRPM", 10.0)
    rig.run_ms(1)
    assert rig.motor.calls == [("set_rpm", 10.0)]


def test_homeoffset_is_stored_and_returned():
    rig = Rig()
    assert rig.read("HOMEOFFSET") == ((0.0,), OFF)
    assert rig.command("HOMEOFFSET", 0.338) == OFF
    value, flags = rig.read("HOMEOFFSET")
    assert abs(value[0] - 0.338) < 1e-6 and flags == OFF


def test_identity_reports_versions_joint_and_spec_hash():
    from joint.spec.version import FIRMWARE_VERSION
    rig = Rig()
    values, flags = rig.read("IDENTITY")
    assert values == (P.PROTOCOL_VERSION,) + FIRMWARE_VERSION + (1, P.SPEC_HASH)
    assert flags == OFF


def test_home_sets_nothomed_and_busy_in_its_reply_then_runs_in_main_loop():
    rig = Rig()
    _enable(rig)
    rig.motor.error = 0.0
    assert rig.command("HOME", 1, 10, 30, 15) == ENABLED | P.FLAG_NOTHOMED | P.FLAG_BUSY
    rig.run_ms(600)
    effects = [call for call in rig.motor.calls if call != ("magnet",)]  # the magnet check only reads
    assert effects[:4] == [("set_current", 15), ("set_hold_current", 15), ("stop", True),
                           ("set_rpm", 10)], "energized (holding) before it settles"
    assert rig.core.flags & P.FLAG_BUSY, "holds BUSY until the end stop"
    rig.motor.error = 31.0
    rig.run_ms(50)
    assert ("set_home",) not in rig.motor.calls, "one PID-error spike is no end stop"
    for _ in range(10):  # the field runs on, the encoder stays: the end stop
        rig.motor.field += 400
        rig.run_ms(5)
    rig.run_ms(200)  # it settles against the stop before zeroing
    assert ("set_home",) in rig.motor.calls
    assert rig.core.flags == 0, "homed, enabled, not busy"
    assert rig.motor.calls[-4:] == [("stop", True), ("set_home",), ("set_current", 20),
                                    ("set_hold_current", 20)], "stop, zero, restore the currents"


def test_home_negative_direction_turns_negative():
    rig = Rig()
    _enable(rig)
    rig.command("HOME", 0, 45, 50, 30)
    rig.run_ms(600)
    assert ("set_rpm", -45) in rig.motor.calls


def test_stop_aborts_homing_and_leaves_it_not_homed():
    rig = Rig()
    _enable(rig)
    rig.command("HOME", 1, 10, 30, 15)
    rig.run_ms(700)
    assert rig.command("STOP", 0) == ENABLED | P.FLAG_NOTHOMED, "STOP clears BUSY in its reply"
    rig.run_ms(2)
    assert ("set_home",) not in rig.motor.calls
    assert rig.core.flags == ENABLED | P.FLAG_NOTHOMED
    assert rig.core._task is None


def test_check_orientation_holds_busy_until_done():
    rig = Rig()
    _enable(rig)
    rig.motor.reached = False
    assert rig.command("CHECKORIENTATION", 2.0) == ENABLED | P.FLAG_BUSY
    rig.run_ms(50)
    assert rig.core.flags & P.FLAG_BUSY
    assert rig.motor.calls[:3] == [("disable_closed_loop",), ("set_inverted", False), ("move_angle", 2.0)]
    rig.motor.reached = True
    rig.run_ms(20)
    assert not rig.core.flags & P.FLAG_BUSY
    moves = [c[1] for c in rig.motor.calls if c[0] == "move_angle"]
    assert moves == [2.0, -2.0, 2.0, -2.0], "two out-and-back pairs"
    assert rig.motor.calls[-2:] == [("set_inverted", False), ("enable_closed_loop",)]


def test_orientation_check_detects_inverted_wiring():
    rig = Rig()
    _enable(rig)
    rig.motor.wiring = -1
    rig.command("CHECKORIENTATION", 2.0)
    rig.run_ms(20)
    assert rig.motor.calls[-2:] == [("set_inverted", True), ("enable_closed_loop",)]
    assert rig.motor.angle == 0.0, "out-and-back moves end where they started"


def test_boot_sequence_is_the_original_setup():
    rig = Rig(boot=False)
    assert rig.core.flags & P.FLAG_BUSY and not rig.core.ready
    rig.run_ms(100)
    names = rig.motor.names()
    assert names[:6] == ["begin", "enable_closed_loop", "set_max_acceleration", "set_max_deceleration",
                         "set_max_velocity", "set_control_threshold"]
    assert rig.motor.calls[2] == ("set_max_acceleration", 100.0)
    assert rig.motor.calls[4] == ("set_max_velocity", 10.0)
    assert rig.motor.calls[5] == ("set_control_threshold", 15.0)
    assert ("move_angle", 1.0) in rig.motor.calls
    assert rig.motor.calls[-4:] == [("stop", True), ("set_current", 0), ("set_hold_current", 0),
                                    ("set_brake_mode", 0)]
    assert rig.core.ready and rig.core.flags == OFF


def test_lasterror_reports_reason_register_and_count():
    rig = Rig()
    rig.xfer(bytes([0x21, 1]), 1)
    rig.xfer(bytes([P.SETCURRENT, 101]), 1)
    values, flags = rig.read("LASTERROR")
    assert values == (P.REJECT_VALUE, P.SETCURRENT, 2)
    assert flags == OFF, "the LASTERROR read itself was fine"
    rig.run_ms(1)
    assert any(line.endswith("rejected a frame for register 0x19: reason %d" % P.REJECT_VALUE)
               for line in rig.lines), rig.lines


def test_a_motor_backend_failure_disables_the_joint_instead_of_crashing():
    rig = Rig(boot=False)

    def broken():
        raise OSError(5, "no reply from the TMC2209")
    rig.motor.begin = broken
    rig.run_ms(5)
    assert rig.core.ready and rig.core.disabled, "boot failed: disabled, but on the bus"
    assert rig.core.flags & P.FLAG_NOTENABLED and not rig.core.flags & P.FLAG_BUSY
    assert any("motor fault" in line and "TMC2209" in line for line in rig.lines), rig.lines
    assert rig.command("SETUP", 20, 20, 0, 0) & P.FLAG_ERROR
    assert rig.core.cached_reply(P.LASTERROR)[0] == P.REJECT_DISABLED


def test_stop_during_check_orientation_ends_it_without_further_moves():
    rig = Rig()
    _enable(rig)
    rig.motor.reached = False
    rig.command("CHECKORIENTATION", 2.0)
    rig.run_ms(50)
    assert rig.command("STOP", 0) & P.FLAG_BUSY == 0
    rig.run_ms(2)
    assert rig.core.task_name is None and not rig.core.flags & P.FLAG_BUSY
    rig.motor.calls = []
    rig.run_ms(12000)
    assert [c for c in rig.motor.calls if c[0].startswith("move")] == [], "no move after the STOP"


def test_a_negative_orientation_angle_checks_the_same_way():
    rig = Rig()
    _enable(rig)
    rig.motor.wiring = 1
    rig.command("CHECKORIENTATION", -2.0)
    rig.run_ms(20)
    assert ("set_inverted", True) not in rig.motor.calls, "a correctly wired motor stays as it is"
    assert [c[1] for c in rig.motor.calls if c[0] == "move_angle"][:2] == [2.0, -2.0]


def test_a_stall_decided_before_the_host_rearmed_is_dropped():
    rig = Rig()
    _enable(rig)
    rig.command("ENABLESTALLGUARD", 6)
    rig.run_ms(1)
    rig.motor.error = 1000.0
    original = rig.core.stall.update

    def rearm_while_sampling(*args):
        stalled = original(*args)
        rig.command("SETUP", 20, 20, 0, 0)  # the IRQ answers "STALL clear" meanwhile
        return stalled
    rig.core.stall.update = rearm_while_sampling
    for _ in range(200):
        rig.run_ms(1)
        rig.motor.error = rig.motor.error + 50.0
    assert not rig.core.flags & P.FLAG_STALL
