"""The S32 image booted on the emulated board (tests/s32_emu.py: Qiling's STM32F401 with the
TMC5130 and TLE5012B models on SPI2/SPI3 and an STM32F4 I2C1 target, in virtual time), driven by
the host's own `Joint`, legacy and v2 links through a `Bus` over the emulator (tests/s32_bus.py):
it boots as J1 with the heap the issue asks to keep free; every legacy register answers as on the
simulated J1; a MOVETOANGLE reaches the TMC5130's XTARGET in usteps and turns the rotor; HOME ends at
the rotor's stop; the deadman stops a move when the host goes quiet; the v2 cycle works.

One boot for the module (about 7 s); the tests run in file order on that joint (homing before the
moves that need it). Each emulated second takes 6 to 18 s of wall time (by the machine's load)."""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterator

import pytest

from bioscara import s32flash
from bioscara.bus.sim import SimBus, SimJointSpec
from bioscara.config import read_config
from bioscara.firmware.spec import protocol as P
from bioscara.joint import Joint
from bioscara.link.legacy import LegacyLink
from bioscara.link.v2 import V2Link
from s32_bus import USTEPS_PER_MOTOR_DEGREE, EmulatedS32Bus, missing

ADDRESS = 0x11  # J1's, from the composed flash's configuration
HEAP_FREE_TARGET = 12 * 1024
J1 = read_config(None).joints["j1"]  # the shipped arm's J1: reduction, limits, homing
DEADMAN_MS = json.loads(s32flash.s32_config("J1"))["deadman_ms"]  # as flashed with the image
# Registers read as values near 0 rather than byte for byte: the encoder's speed still settles
# after the boot's orientation check (rpm), and the simulated rotor rests within an AS5600 count
# (0.088 degrees) of its start, the S32's within a TLE5012B count (0.011 degrees).
AT_REST = {P.GETENCODERRPM: 2.0, P.ANGLEMOVED: 0.1}
# The sensor's own angle at home: where each board's magnet happens to sit (0..360 degrees).
BOARDS_OWN = {P.ENCODERZERO}


@pytest.fixture(scope="module")
def bus(tmp_path_factory: pytest.TempPathFactory) -> Iterator[EmulatedS32Bus]:
    why = missing()
    if why is not None:
        pytest.skip(why)
    flash = EmulatedS32Bus.flash_for("J1", tmp_path_factory.mktemp("s32"))
    emulated = EmulatedS32Bus(flash)
    yield emulated
    emulated.close()


@pytest.fixture(scope="module")
def joint(bus: EmulatedS32Bus) -> Iterator[Joint]:
    j1 = Joint("J1", ADDRESS, bus, reduction=J1.reduction, min=J1.min, max=J1.max, max_velocity=J1.max_velocity)
    j1.init()
    yield j1
    j1.close()


def test_the_emulated_s32_boots_as_j1_and_joins_the_bus(bus: EmulatedS32Bus) -> None:
    assert "J1 INFO J1 ready at 0x11" in bus.log
    booted = re.search(r"J1 INFO booted: (\d+) bytes of heap free", bus.log)
    assert booted is not None, bus.log
    assert int(booted.group(1)) >= HEAP_FREE_TARGET
    assert bus.scan(0x10, 0x12) == [ADDRESS]


def test_the_main_loop_drives_the_tmc5130_without_a_motor_fault(bus: EmulatedS32Bus) -> None:
    before = bus.board()["datagrams"]
    bus.sleep(0.02)
    assert bus.board()["datagrams"] > before + 20, "the 1 kHz loop reads the driver every iteration"
    assert "motor fault" not in bus.log and " ERROR " not in bus.log, bus.log


def test_every_legacy_register_answers_as_on_the_simulated_joint(bus: EmulatedS32Bus, joint: Joint) -> None:
    identity = joint.identity()
    assert identity.spec_matches and identity.joint_id == 1
    simulated = SimBus([SimJointSpec("J1", ADDRESS, J1.reduction, J1.min, J1.max, 0.0)])
    reference = LegacyLink(simulated, ADDRESS, "J1")
    wrong = []
    for reg in P.REGISTERS:
        if not reg.readable:
            continue
        values, flags = joint.link.read(reg)
        expected, expected_flags = reference.read(reg)
        if reg.addr in AT_REST:
            same = all(abs(v) < AT_REST[reg.addr] for v in values + expected)
        elif reg.addr in BOARDS_OWN:
            same = all(0.0 <= v < 360.0 for v in values + expected)
        else:
            same = values == expected
        if not same or flags != expected_flags:
            wrong.append(f"{reg.name}: S32 {values} flags {P.describe_flags(flags)}, simulator {expected} "
                         f"flags {P.describe_flags(expected_flags)}")
    assert not wrong, "\n".join(wrong)


def _home_at_a_stop(bus: EmulatedS32Bus, joint: Joint) -> int:
    """Home J1 against a stop 3 motor degrees below the rotor (J1 homes downward); the stop's rotor
    position in usteps."""
    homing = J1.homing
    wall = bus.board()["rotor"] - round(3 * USTEPS_PER_MOTOR_DEGREE)
    bus.set_wall(wall, side=-1)
    joint.enable(J1.drive_current, J1.hold_current)
    joint.home(homing.direction * homing.speed, homing.threshold, homing.current, timeout=5.0)
    return wall


@pytest.fixture
def homed(bus: EmulatedS32Bus, joint: Joint) -> None:
    """J1 homed (by the homing test when it ran first), the stop taken away: the rotor jumps to
    the pole the field holds (it slipped one at the stop)."""
    if not joint.is_homed():
        _home_at_a_stop(bus, joint)
    bus.set_wall(None)


def test_home_ends_at_the_rotor_s_stop(bus: EmulatedS32Bus, joint: Joint) -> None:
    wall = _home_at_a_stop(bus, joint)
    rotor = bus.board()["rotor"]
    assert joint.is_homed()
    assert 0 <= rotor - wall < 512, f"rotor {rotor - wall} usteps from the stop"  # at it, or < 2 full steps back
    # Zero is where the joint noticed the stall: the rotor pressed against the stop, the field
    # leading it by up to 2 full steps (3.6 motor degrees).
    position = joint.get_position()
    print(f"S32 homing: rotor {rotor - wall} usteps from the stop, zero "
          f"{math.degrees((position - J1.min) * J1.reduction):.2f} motor degrees from it")
    assert position == pytest.approx(J1.min, abs=math.radians(3.6) / J1.reduction)


def _driver_register_changes(bus: EmulatedS32Bus, name: str, before: int, within_ms: int = 20) -> int:
    """The TMC5130 register `name` once the main loop has written a new value (a command is taken
    in a main-loop iteration after its transaction)."""
    for _ in range(within_ms):
        bus.sleep(0.001)
        value = bus.board()["tmc"][name]
        if value != before:
            return value
    raise AssertionError(f"{name} still {before} after {within_ms} ms")


@pytest.mark.usefixtures("homed")
def test_movetoangle_reaches_xtarget_in_usteps_and_turns_the_rotor(bus: EmulatedS32Bus, joint: Joint) -> None:
    joint.set_max_velocity(J1.max_velocity)  # homing left its own speed
    joint.set_max_acceleration(J1.max_acceleration)
    bus.sleep(0.005)
    start = bus.board()
    (start_degrees,) = joint.read_register("ANGLEMOVED")  # the encoder's motor degrees since home
    target = J1.min + 0.015  # joint rad: about 27 motor degrees from the stop
    joint.set_position(target)
    xtarget = _driver_register_changes(bus, "XTARGET", start["tmc"]["XTARGET"])
    # The firmware moves by the encoder's distance to the target, in usteps from where the driver
    # stands: within a TLE5012B count (1.5625 usteps, the encoder may tick between the reads) and
    # the rounding to a ustep.
    distance = (joint.transmission.motor_degrees(target) - start_degrees) * USTEPS_PER_MOTOR_DEGREE
    assert xtarget - start["tmc"]["XACTUAL"] == pytest.approx(distance, abs=2.6)
    rotor = start["rotor"]
    for _ in range(100):  # until the ramp has ended and the rotor stands (1 s at most)
        bus.sleep(0.01)
        joint.get_flags()  # the host keeps talking, as during any move
        board = bus.board()
        if board["VACTUAL"] == 0 and board["rotor"] == rotor:
            break
        rotor = board["rotor"]
    # The rotor turns the distance, within the closed loop's re-synchronisation threshold.
    assert bus.board()["rotor"] - start["rotor"] == pytest.approx(distance, abs=16)
    assert joint.get_position() == pytest.approx(target, abs=math.radians(0.1) / J1.reduction)


def test_the_deadman_stops_a_move_when_the_host_goes_quiet(bus: EmulatedS32Bus, joint: Joint) -> None:
    joint.set_velocity(0.1)  # joint rad/s: 33 motor rpm
    for _ in range(10):
        bus.sleep(0.01)
        joint.get_flags()
    assert bus.board()["tmc"]["VMAX"] > 0 and joint.is_enabled()
    quiet_us = bus.now_us
    stopped_after_ms = None
    while bus.now_us - quiet_us < 3 * DEADMAN_MS * 1000:
        bus.sleep(0.002)
        if stopped_after_ms is None and bus.board()["tmc"]["VMAX"] == 0:
            stopped_after_ms = (bus.now_us - quiet_us) / 1000
    still = bus.board()
    bus.sleep(0.02)
    assert stopped_after_ms is not None, "the motor still turns"
    print(f"S32 deadman: VMAX 0 {stopped_after_ms} ms after the host went quiet (deadman {DEADMAN_MS} ms)")
    # Within a main-loop iteration and the 2 ms sampling of the driver's register.
    assert DEADMAN_MS <= stopped_after_ms <= DEADMAN_MS + 4
    assert bus.board()["rotor"] == still["rotor"] and still["VACTUAL"] == 0
    assert "deadman: no I2C traffic" in bus.log
    joint.get_flags()
    assert not joint.is_enabled()


@pytest.mark.usefixtures("homed")
def test_v2_cycles_a_setpoint_in_and_a_checked_state_block_out(bus: EmulatedS32Bus, joint: Joint) -> None:
    joint.enable(J1.drive_current, J1.hold_current)
    start, rotor = joint.get_position(), bus.board()["rotor"]
    joint.use_v2()
    assert isinstance(joint.link, V2Link)
    target = J1.min + 0.02
    setpoint = joint.position_command(target)
    states = []
    for _ in range(40):
        states.append(joint.cycle(setpoint))
        bus.sleep(0.01)
    stats = joint.link.stats
    arrived = [state for state in states if state is not None]
    print(f"S32 v2: {len(arrived)} of {len(states)} cycles brought a state; {stats.bad_states} state blocks "
          f"failed their CRC, {stats.stale_states} stale")
    # Nothing refused, no verdict lost, no state block torn: the joint publishes one only while
    # no read from it is in progress (SR2's TRA); every state taken lies on the way, the rotor
    # within a full step of the field (1.8 motor degrees: it rings about the target when the
    # ramp ends, by about half a degree; beyond a full step it would be slipping).
    assert (stats.link_rejects, stats.rejected, stats.unacknowledged, stats.bad_states) == (0, 0, 0, 0), stats
    assert len(arrived) >= len(states) // 2
    low, high = sorted((start, target))
    full_step = math.radians(1.8) / J1.reduction
    astray = [position for position, _ in arrived if not low - full_step <= position <= high + full_step]
    assert not astray, f"states off the way from {start} to {target}: {astray}"
    slack = math.radians(0.1) / J1.reduction
    turned = math.degrees((target - start) * J1.reduction) * USTEPS_PER_MOTOR_DEGREE
    assert bus.board()["rotor"] - rotor == pytest.approx(turned, abs=16)  # the closed loop's threshold
    position, velocity = arrived[-1]
    assert position == pytest.approx(target, abs=slack)
    joint.use_legacy()
    joint.check_com()


def test_use_v2_syncs_whatever_the_main_loop_s_phase(bus: EmulatedS32Bus, joint: Joint) -> None:
    # The sync needs each 1 ms frame acknowledged before the next; the S32's main loop takes
    # about as long. A swap held off past the next transaction's start (once by the bus's BUSY)
    # locked onto that start and left every ack two frames behind: the sync never ended.
    for switch in range(8):
        bus.sleep(switch * 0.00037)  # a new phase of the main loop against the host's frames
        joint.use_v2()
        assert isinstance(joint.link, V2Link) and joint.link.stats.bad_states == 0
        joint.use_legacy()
    joint.check_com()
