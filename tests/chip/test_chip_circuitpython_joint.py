"""The CircuitPython joint on the emulated Pico with its devices (TMC2209, AS5600, rotor) and the
joint bus, flashed as `bioscara flash --runtime circuitpython` leaves CIRCUITPY and driven over the
bus as a host drives it: every register reads as on the MicroPython joint at 100 and 400 kHz; the
host's switch to protocol v2 is refused and it stays on legacy; MOVEANGLE turns the rotor; the
deadman stops it; HOME ends at the stop. One boot of each runtime for the module (CircuitPython
boots in about 4.5 s of emulated time)."""

from __future__ import annotations

import struct
from collections.abc import Iterator
from pathlib import Path

import pytest

from chip import fsimage
from chip.board import EmulatedPico
from chip.i2c import ChipBus, JointBusClient, joint_bus_plugin
from chip.joint_devices import JOINT_DEVICES_PLUGIN, USTEPS_PER_REV, JointDevices
from chip_bus import wait_on_bus
from chip.testing import joint_image, read_console_until, requires_chip, requires_circuitpython  # noqa: F401 (a fixture)
from joint.spec import protocol as P

pytestmark = [requires_chip, requires_circuitpython]

ADDRESS = 0x11  # J1
KEEP_ALIVE_US = 10_000  # the host's poll period while the joint moves (deadman 50 ms)
USTEPS_PER_DEG = USTEPS_PER_REV / 360


def wait_at_rest(bus: JointBusClient, polls: int = 200) -> None:
    """Poll until the driver's ramp has stood still three reads running (20 ms apart): after the
    boot's orientation check the closed loop may still be correcting the rotor for a while."""
    still = 0
    for _ in range(polls):
        t = bus.transfer(ADDRESS, bytes([P.GETDRIVERRPM]), 5, gap_us=20_000)
        still = still + 1 if t.ack and t.data[:4] == bytes(4) else 0
        if still == 3:
            return
    raise AssertionError(f"the driver still turns {polls * 20} ms after the boot")


def register_replies(bus: JointBusClient) -> dict[tuple[int, int], bytes]:
    """Every readable register as the original host reads it at rest, at 100 and 400 kHz:
    (kHz, reg) -> reply."""
    wait_on_bus(bus)  # the joint joins the bus after its boot message
    wait_at_rest(bus)
    out = {}
    for khz in (100, 400):
        bus.set_khz(khz)
        for reg in P.REGISTERS:
            if reg.readable:
                t = bus.transfer(ADDRESS, bytes([reg.addr]), reg.rsize + 1, gap_us=2000)
                assert t.ack and not t.timed_out, f"{reg.name} at {khz} kHz"
                out[khz, reg.addr] = t.data
    bus.set_khz(400)
    return out


@pytest.fixture(scope="module")
def micropython_replies(joint_image: Path) -> dict[tuple[int, int], bytes]:  # noqa: F811
    """The MicroPython J1's replies at rest after boot, on the same devices."""
    with EmulatedPico(joint_image, plugins=[JOINT_DEVICES_PLUGIN, joint_bus_plugin()]) as pico:
        assert b"ready at 0x11" in read_console_until(pico.port(), b"ready at 0x11", 120)
        return register_replies(JointBusClient(pico))


@pytest.fixture(scope="module")
def circuitpython_joint(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[EmulatedPico, JointBusClient, str]]:
    image = tmp_path_factory.mktemp("cp") / "circuitpy.img"
    fsimage.circuitpython_joint_image("J1", image)
    with EmulatedPico(image, runtime="circuitpython", plugins=[JOINT_DEVICES_PLUGIN, joint_bus_plugin()]) as pico:
        # After boot: the heap left, then how often the loop collects (set by its first iterations).
        console = read_console_until(pico.port(), b"collecting every", 240).decode(errors="replace")
        assert "ready at 0x11" in console and "collecting every" in console, console + pico.stderr_text()
        print(console)
        yield pico, JointBusClient(pico), console


def test_every_register_reads_as_on_the_micropython_joint(micropython_replies, circuitpython_joint) -> None:
    _, bus, console = circuitpython_joint
    assert "CircuitPython joint" in console and "heap free" in console
    replies = register_replies(bus)
    # The encoder's speed still settles after the boot's orientation check (a fraction of an rpm,
    # decaying): on both, at their own moment. It is compared as a value, the rest byte for byte.
    settling = P.GETENCODERRPM
    wrong = [f"{P.register(reg).name} at {khz} kHz: CircuitPython {replies[khz, reg].hex()}, "
             f"MicroPython {expected.hex()}" for (khz, reg), expected in micropython_replies.items()
             if reg != settling and replies[khz, reg] != expected]
    assert not wrong, "\n".join(wrong)
    for khz in (100, 400):
        cp, mp = replies[khz, settling], micropython_replies[khz, settling]
        assert cp[4] == mp[4] and abs(struct.unpack("<f", cp[:4])[0]) < 2 and abs(struct.unpack("<f", mp[:4])[0]) < 2


def test_register_reads_back_to_back_are_answered_within_an_iteration(circuitpython_joint) -> None:
    """Three register reads back to back, 20 times at 100 Hz (a host's poll): each waits for a
    poll inside the loop's iteration, not for the iteration's end (the median SCL held of each is
    under 1 ms; a collection, 10 ms, may land in one)."""
    pico, bus, _ = circuitpython_joint
    wait_on_bus(bus)
    names = ("ANGLEMOVED", "GETENCODERRPM", "PING")
    cycle = [(ADDRESS, bytes([P.register(n).addr]), P.register(n).rsize + 1) for n in names]
    results = bus.schedule(cycle, repeat=20, period_us=10_000)
    assert all(t.ack and not t.timed_out for t in results)
    for k, name in enumerate(names):
        held = sorted(round(t.scl_held_us) for t in results[k::len(names)])
        assert held[len(held) // 2] < 1000, (name, held)


def test_a_host_asking_for_v2_is_refused_and_stays_on_legacy(circuitpython_joint) -> None:
    from bioscara.errors import CommError
    from bioscara.joint import Joint

    _, client, _ = circuitpython_joint
    joint = Joint("J1", ADDRESS, ChipBus(client))
    joint.init()
    assert joint.identity().spec_matches
    with pytest.raises(CommError):
        joint.use_v2()
    assert joint.protocol == "legacy"
    joint.check_com()  # the legacy map answers as before
    joint.close()


def _frame(reg: int, fmt: str = "", *values: float) -> tuple[int, bytes, int]:
    """A command as the original host sends it: [reg, payload], repeated START, the flags."""
    return ADDRESS, bytes([reg]) + (struct.pack("<" + fmt, *values) if fmt else b""), 1


def _session(bus: JointBusClient, commands: list, ms: int) -> list:
    """`commands`, then PINGs for `ms` milliseconds, one transaction every KEEP_ALIVE_US of
    emulated time (the deadman is 50 ms: the joint never waits on this process); asserts every
    command was accepted; returns the PINGs."""
    pings = [(ADDRESS, bytes([P.PING]), 2)] * (ms * 1000 // KEEP_ALIVE_US)
    done = bus.schedule(commands + pings, gap_us=KEEP_ALIVE_US)
    for t in done[:len(commands)]:
        assert t.ack and not t.data[0] & P.FLAG_ERROR, f"{t.write.hex()}: flags {t.data.hex()}"
    return done[len(commands):]


FAST = [_frame(P.SETUP, "BBBB", 50, 20, 0, 0), _frame(P.SETMAXVELOCITY, "f", 360.0),
        _frame(P.SETMAXACCELERATION, "f", 7200.0)]


def test_moveangle_turns_the_rotor(circuitpython_joint) -> None:
    pico, bus, _ = circuitpython_joint
    devices = JointDevices(pico)
    before = devices.state()
    _session(bus, [*FAST, _frame(P.MOVEANGLE, "f", 90.0)], 1500)
    after = devices.state()
    moved = after["rotor"]["position"] - before["rotor"]["position"]
    # The closed loop re-synchronises the driver to the encoder at 15 usteps: the move ends within
    # that plus a count (12.5 usteps) of 90 degrees.
    assert abs(moved - 90 * USTEPS_PER_DEG) <= 15 + 12.5, moved
    angle = bus.transfer(ADDRESS, bytes([P.ANGLEMOVED]), 5, gap_us=1000).data
    assert abs(struct.unpack("<f", angle[:4])[0] - 90.0) < 0.2


def test_the_deadman_stops_the_rotor_when_the_host_goes_quiet(circuitpython_joint) -> None:
    pico, bus, _ = circuitpython_joint
    devices = JointDevices(pico)
    devices.capture_steps(True)
    polls = _session(bus, [*FAST, _frame(P.SETRPM, "f", 30.0)], 300)
    assert all(not t.data[1] & P.FLAG_NOTENABLED for t in polls), "enabled while the host polls"
    quiet_ns = (polls[-1].start_us + polls[-1].total_us) * 1000
    flags = bus.transfer(ADDRESS, bytes([P.PING]), 2, gap_us=200_000).data[1]  # 200 ms of silence first
    times = devices.capture_steps(False)
    assert flags & P.FLAG_NOTENABLED, "the deadman disabled the joint"
    last_step_ms = (times[-1] - quiet_ns) / 1e6
    print(f"CircuitPython deadman: last step {last_step_ms:.1f} ms after the host went quiet (deadman 50 ms)")
    assert 50 < last_step_ms < 50 + 60
    still = devices.state()["rotor"]["position"]
    _session(bus, [], 50)
    assert devices.state()["rotor"]["position"] == still


def test_home_ends_at_the_end_stop(circuitpython_joint) -> None:
    pico, bus, _ = circuitpython_joint
    devices = JointDevices(pico)
    stop = devices.stops(low=-3.0)["low"]
    # J1's homing from the default arm configuration: 10 motor rpm, |PID error| > 30, 15 % current.
    setup = [_frame(P.SETUP, "BBBB", 20, 20, 0, 0), _frame(P.SETMAXACCELERATION, "f", 3600.0)]
    flags = _session(bus, [*setup, _frame(P.HOME, "BBBB", 0, 10, 30, 15)], 20)[-1].data[1]
    assert flags & P.FLAG_BUSY
    for _ in range(40):
        flags = _session(bus, [], 250)[-1].data[1]
        if not flags & P.FLAG_BUSY:
            break
    state = devices.state()
    devices.stops()
    assert not flags & P.FLAG_BUSY, "homing ended"
    assert not flags & P.FLAG_NOTHOMED
    assert 0 <= state["rotor"]["position"] - stop < 512  # at the stop, or slipped back < 2 full steps
    angle = struct.unpack("<f", bus.transfer(ADDRESS, bytes([P.ANGLEMOVED]), 5, gap_us=1000).data[:4])[0]
    blocked = state["rotor"]["blockedSteps"]
    print(f"CircuitPython homing: rotor {state['rotor']['position'] - stop} usteps from the stop, encoder "
          f"{angle:.2f} deg from its new zero, noticed after {blocked} blocked steps")
    # Zero is where the joint noticed the stall: the rotor buzzing against the stop, within the
    # same 2 full steps (3.6 deg) of it (MicroPython's faster loop notices it within 1 deg).
    assert abs(angle) < 3.6
