"""The Pico backend on the emulated Pico against the joint's device fakes (chip/src/joint-devices.mjs).

The board starts from the littlefs image of exactly the files `bioscara flash --joint J1` deploys
(chip/fsimage.py; tests/chip/test_chip_joint.py runs the flash itself) and boots from /main.py;
that boot (driver set-up, orientation check on the rotor) is the first test, then current commands
over the joint bus (chip-i2c's emulated controller on I2C0) reach the driver. The later tests reach
the joint through the raw REPL (mpremote): Ctrl-C ends main.py's loop (which leaves the motor
safe), a soft reset gives a fresh heap, and a script on the board builds a fresh `JointController` with `startup.build(machine)` and
runs its main loop, handing it frames with `on_frame` and `host_seen` as the I2C target adapter
would: the command path there is the REPL, not I2C0 (5-byte commands over I2C0 do not arrive
whole yet: tests/chip/test_joint_bus.py). Every figure is taken on the emulated clock:
pulses on the STEP pin, the TMC2209's register file and the rotor model.
"""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from bioscara.firmware.spec import protocol as P
from bioscara.firmware.pico import tmc2209 as tmc
from bioscara.firmware.pico import tmc2209_setup as tmc_setup
from chip.board import EmulatedPico
from chip.i2c import JointBusClient, joint_bus_plugin
from chip.joint_devices import JOINT_DEVICES_PLUGIN, USTEPS_PER_REV, JointDevices
from chip.testing import joint_image, read_console_until, requires_chip  # noqa: F401 (a fixture)

pytestmark = requires_chip

USTEPS_PER_DEG = USTEPS_PER_REV / 360

# On the board, after main.py was interrupted: a fresh controller and its main loop in emulated time.
BOARD_HELPERS = """
import gc, json, machine, rp2, struct, time
from joint import startup
from joint.config import schema as config
from joint.spec import protocol as P

# J1's configuration with faster boot limits, so the orientation check of every fresh controller
# takes ~0.1 s instead of ~0.6 s of emulated time (it is tested as deployed by the first test).
with open(config.CONFIG_FILE) as f:
    _cfg = json.load(f)
_cfg["boot"].update(max_velocity=200.0, max_acceleration=8000.0)
with open("/chip_test_config.json", "w") as f:
    json.dump(_cfg, f)

core = cfg = log = None

def make():
    global core, cfg, log
    core = cfg = log = None  # the previous test's controller frees its heap before the next is built
    gc.collect()
    rp2.PIO(0).remove_program()
    core, cfg, log = startup.build(machine, "/chip_test_config.json")

stats = [0, 0, 0]  # iterations, longest us, iterations over 4 ms (the ramp's dt clamp)

def run(ms, host=True):
    end = time.ticks_add(time.ticks_ms(), ms)
    nxt = time.ticks_ms()
    last = time.ticks_us()
    while time.ticks_diff(end, time.ticks_ms()) > 0:
        if host:
            core.host_seen()
        core.service()
        now = time.ticks_us()
        took = time.ticks_diff(now, last)
        last = now
        stats[0] += 1
        if took > stats[1]:
            stats[1] = took
        if took > 4000:
            stats[2] += 1
        nxt = time.ticks_add(nxt, 1)
        while time.ticks_diff(nxt, time.ticks_ms()) > 0:
            machine.idle()

def until(cond, limit_ms, host=True):
    end = time.ticks_add(time.ticks_ms(), limit_ms)
    while not cond() and time.ticks_diff(end, time.ticks_ms()) > 0:
        run(1, host)
    return cond()

def send(reg, fmt='', *values):
    frame = bytes([reg]) + (struct.pack('<' + fmt, *values) if fmt else b'')
    core.on_frame(frame, len(frame))
    core.host_seen()

def fast():
    send(P.SETUP, 'BBBB', 50, 20, 0, 0)
    send(P.SETMAXVELOCITY, 'f', 360.0)
    send(P.SETMAXACCELERATION, 'f', 7200.0)
    run(5)
"""


@pytest.fixture(scope="module")
def booted(joint_image: Path):
    """J1 booted from /main.py with its devices and the joint bus controller on I2C0:
    (pico, devices, boot console text, device state after the boot)."""
    with EmulatedPico(joint_image, plugins=[JOINT_DEVICES_PLUGIN, joint_bus_plugin()]) as pico:
        console = read_console_until(pico.port(), b"ready at 0x11", 120).decode(errors="replace")
        devices = JointDevices(pico)
        yield pico, devices, console, devices.state()


@pytest.fixture(scope="module")
def joint(booted):
    """After the tests on main.py: main.py stopped, then a soft reset (a fresh heap: how much the
    interrupted loop leaves referenced depends on where Ctrl-C lands, 0-12 KB measured, and the
    later tests' moves failed on MemoryError after the worst), a controller of the tests' own
    booted and ready."""
    pico = booted[0]
    pico.exec(BOARD_HELPERS, soft_reset=True)
    assert "True" in pico.exec("make()\nprint(until(lambda: core.ready, 5000))", timeout=120)
    return booted


def board(pico: EmulatedPico, code: str, timeout: float = 120.0) -> str:
    return pico.exec(code, timeout=timeout)


def test_boot_configures_the_driver_and_checks_orientation_on_the_rotor(booted) -> None:
    pico, devices, console, state = booted
    assert "J1 INFO J1 ready at 0x11" in console, console
    driver = state["driver"]
    writes = [name for name, _value, _t in driver["writes"]]
    assert writes[:7] == ["GSTAT", "GCONF", "CHOPCONF", "PWMCONF", "TPOWERDOWN", "TPWMTHRS", "IHOLD_IRUN"]
    assert driver["microsteps"] == 256  # MRES from CHOPCONF (GCONF.mstep_reg_select)
    assert driver["regs"]["GCONF"] == tmc.gconf(False)
    assert driver["ifcnt"] == len(writes)
    # The orientation check turned the rotor +1 deg / -1 deg at least twice each, back to where it was.
    one_degree = round(USTEPS_PER_DEG)
    assert driver["steps"] >= 4 * one_degree
    assert driver["steps"] % (2 * one_degree) == 0
    assert state["rotor"]["position"] == 0
    # Boot ends with the driver at 0 % (CS 0) and freewheel: IHOLD_IRUN = 0.
    assert (driver["ihold"], driver["irun"]) == (0, 0)
    assert state["encoder"]["conf"] == 0x0300  # slow filter 2x (SF=3), as configured


def test_current_commands_over_the_joint_bus_reach_the_driver(booted) -> None:
    """The whole path: the emulated controller on I2C0 at 400 kHz, main.py's I2C target and loop,
    the Pico backend, UART1, the TMC2209's register file."""
    pico, devices, _, _ = booted
    bus = JointBusClient(pico)
    _, cs_max = tmc_setup.current_scale(0.11, 1.5)
    # The console's "ready" comes before main.py joins the bus: wait 100 ms (emulated) and PING.
    ping = bus.transfer(0x11, bytes([P.PING]), 2, gap_us=100_000)
    assert ping.ack and ping.data[0] == P.ACK, ping
    for reg, percent in ((P.SETCURRENT, 70), (P.SETHOLDCURRENT, 30)):
        sent = bus.transfer(0x11, bytes([reg, percent]), 1, gap_us=2000)
        # 20 ms later on the emulated clock (the main loop applies a command within a period):
        last = bus.transfer(0x11, bytes([P.LASTERROR]), 5, gap_us=20000)
        assert sent.ack and last.ack, (sent, last)
    driver = devices.state()["driver"]
    expected = (tmc.percent_to_cs(70, cs_max), tmc.percent_to_cs(30, cs_max))
    assert (driver["irun"], driver["ihold"]) == expected, (sent, last, driver["writes"][-3:])
    angle = bus.transfer(0x11, bytes([P.ANGLEMOVED]), 5, gap_us=2000)
    assert struct.unpack("<f", angle.data[:4])[0] == 0.0  # the rotor is where the boot left it


def test_setup_writes_the_configured_currents(joint) -> None:
    pico, devices, _, _ = joint
    board(pico, "send(P.SETUP, 'BBBB', 60, 25, 0, 0)\nrun(5)")
    vsense, cs_max = tmc_setup.current_scale(0.11, 1.5)
    driver = devices.state()["driver"]
    assert (driver["irun"], driver["ihold"]) == (tmc.percent_to_cs(60, cs_max), tmc.percent_to_cs(25, cs_max))
    assert driver["vsense"] == vsense
    assert driver["enabled"]  # ENN low after begin()


def test_moveangle_turns_the_rotor_the_commanded_angle(joint) -> None:
    pico, devices, _, _ = joint
    board(pico, "fast()")
    before = devices.state()
    out = board(pico, "a0 = core.hal.angle_moved()\nsend(P.MOVEANGLE, 'f', 90.0)\nrun(20)\n"
                      "print(until(lambda: not core.positioning, 3000), (core.hal.angle_moved() - a0) / 4096)")
    after = devices.state()
    reached, angle = out.split()
    assert reached == "True"
    steps = after["driver"]["steps"] - before["driver"]["steps"]
    field = after["driver"]["position"] - before["driver"]["position"]
    moved = after["rotor"]["position"] - before["rotor"]["position"]
    assert field == moved  # one microstep per pulse at MRES 256, and the rotor follows
    assert steps >= moved  # pulses counted on STEP: the move, plus any closed-loop correction back and forth
    # Boot leaves the closed loop on: it re-synchronises the driver to the encoder whenever they
    # differ by the control threshold (15 usteps), so the move ends within that plus a count.
    assert abs(moved - 90 * USTEPS_PER_DEG) <= 15 + 12.5, moved
    assert abs(float(angle) - 90.0) < 0.2  # the encoder, 0.088 deg a count


def _steady_rate(times_ns: list[float], skip_s: float, span_s: float) -> float:
    """Least-squares steps per second over [first + skip, first + skip + span] of STEP times."""
    import numpy as np

    t = np.asarray(times_ns) * 1e-9
    t = t[(t >= t[0] + skip_s) & (t <= t[0] + skip_s + span_s)]
    slope, _ = np.polyfit(t, np.arange(len(t)), 1)
    return float(slope)


def _setrpm_rate(pico: EmulatedPico, devices: JointDevices, rpm: float, collect: bool) -> tuple[float, str]:
    """Pulses/s over 200 ms of SETRPM `rpm` after a 50 ms ramp; with `collect`, a garbage
    collection half way (the firmware allocates ~320 bytes per service(), so one comes about every
    second anyway). The heap is collected before, so no other collection falls in the window."""
    board(pico, "fast()")
    devices.capture_steps(True)
    mid = "run(100)\ngc.collect()\nrun(100)" if collect else "run(200)"
    out = board(pico, f"import gc\ngc.collect()\nsend(P.SETRPM, 'f', {rpm})\nrun(50)\nstats[:] = [0, 0, 0]\n"
                      f"{mid}\nprint(stats)\nsend(P.SETRPM, 'f', 0.0)\nrun(50)")
    return _steady_rate(devices.capture_steps(False), 0.05, 0.2), out.strip()


def test_setrpm_holds_the_speed_within_one_percent_between_collections(joint) -> None:
    pico, devices, _, _ = joint
    rate, loop = _setrpm_rate(pico, devices, 30.0, collect=False)
    expected = 30 / 60 * USTEPS_PER_REV  # usteps/s, one pulse each at MRES 256
    print(f"SETRPM 30: {rate:.1f} pulses/s, expected {expected:.1f} ({(rate / expected - 1) * 100:+.3f} %); "
          f"main loop [iterations, longest us, over 4 ms] {loop}")
    assert abs(rate / expected - 1) < 0.01


@pytest.mark.xfail(strict=True, reason="a garbage collection (~17 ms) outlasts the ramp's 4-period dt clamp, "
                                       "so the ramp loses the difference: issue 8's figures, fixed elsewhere")
def test_setrpm_holds_the_speed_within_one_percent_across_a_collection(joint) -> None:
    pico, devices, _, _ = joint
    rate, loop = _setrpm_rate(pico, devices, 30.0, collect=True)
    expected = 30 / 60 * USTEPS_PER_REV
    print(f"SETRPM 30 with a collection: {rate:.1f} pulses/s ({(rate / expected - 1) * 100:+.3f} %); "
          f"main loop [iterations, longest us, over 4 ms] {loop}")
    assert abs(rate / expected - 1) < 0.01


def test_deadman_stops_the_motor_when_the_host_goes_quiet(joint) -> None:
    pico, devices, _, _ = joint
    board(pico, "fast()")
    devices.capture_steps(True)
    # One script: between two scripts nothing runs the main loop on the board.
    out = board(pico, "send(P.SETRPM, 'f', 30.0)\nrun(100)\nquiet = time.ticks_us()\nrun(150, host=False)\n"
                      "print('quiet', quiet, core.flags & P.FLAG_NOTENABLED, core.qd_set)")
    times = devices.capture_steps(False)
    assert "deadman: no I2C traffic for" in out, out
    quiet_us, notenabled, setpoint = out.split("quiet", 1)[1].split()
    assert int(notenabled) and float(setpoint) == 0.0
    last_step_ms = (times[-1] / 1000 - int(quiet_us)) / 1000  # ticks_us is the emulated us (< 2**30)
    print(f"deadman: last step {last_step_ms:.1f} ms after the host went quiet (deadman 50 ms)")
    assert 50 < last_step_ms < 50 + 40  # the deadman, then the hard stop ramp and a loop period or two
    still = devices.state()["rotor"]["position"]
    board(pico, "run(30, host=False)")
    assert devices.state()["rotor"]["position"] == still


def test_encoder_nacks_during_a_move_are_dropped_samples_not_a_crash(joint) -> None:
    pico, devices, _, _ = joint
    board(pico, "fast()")
    start = devices.state()["rotor"]["position"]
    devices.encoder_faults(nack=30)
    out = board(pico, "a0 = core.hal.angle_moved()\nsend(P.MOVEANGLE, 'f', 45.0)\nrun(20)\n"
                      "print('done', until(lambda: not core.positioning, 3000), core.disabled, "
                      "core.hal._enc.errors, (core.hal.angle_moved() - a0) / 4096)")
    done, disabled, errors, angle = out.split("done", 1)[1].split()
    moved = (devices.state()["rotor"]["position"] - start) / USTEPS_PER_DEG
    print(f"45 deg move with 30 encoder NACKs: encoder {angle} deg, rotor {moved:.3f} deg")
    assert (done, disabled) == ("True", "False")
    assert int(errors) == 30
    assert abs(float(angle) - moved) < 0.1  # the count stayed right across the missed samples
    assert abs(moved - 45.0) < 1.0


def test_home_drives_into_the_end_stop_and_zeroes_there(joint) -> None:
    pico, devices, _, _ = joint
    board(pico, "send(P.SETUP, 'BBBB', 20, 20, 0, 0)\nsend(P.SETMAXACCELERATION, 'f', 3600.0)\nrun(5)")
    stop = devices.stops(low=-3.0)["low"]
    # J1's homing from the default arm configuration: 10 motor rpm, |PID error| > 30, 15 % current.
    out = board(pico, "send(P.HOME, 'BBBB', 0, 10, 30, 15)\nrun(5)\n"
                      "print('done', until(lambda: not core.flags & P.FLAG_BUSY, 8000), core.flags, "
                      "core.hal.angle_moved() / 4096)")
    state = devices.state()
    devices.stops()
    done, flags, angle = out.split("done", 1)[1].split()
    blocked = state["rotor"]["blockedSteps"]
    print(f"homing: {out.strip()}; rotor {state['rotor']}; noticed after {blocked} blocked steps "
          f"({blocked / (10 / 60 * USTEPS_PER_REV) * 1000:.0f} ms)")
    assert done == "True"
    assert "J1 INFO homed" in out
    assert not int(flags) & 0x04  # NOTHOMED cleared
    # At the stop, or fallen back by less than half an electrical period (2 full steps): a stepper
    # driven on against a stop slips and buzzes there until the firmware notices.
    assert 0 <= state["rotor"]["position"] - stop < 512
    assert blocked > 0
    assert abs(float(angle)) < 1.0  # zero is at the stop (the encoder's frame)


@pytest.mark.xfail(strict=True, reason="a failed TMC2209 write after boot is only counted (PicoStepper.faults, "
                                       ".fault); nothing reaches the console")
def test_a_driver_write_failing_after_boot_is_reported_on_the_console(joint) -> None:
    pico, devices, _, _ = joint
    devices.driver_faults(echo=False)  # the wire to RX broken: no echo, every write fails its check
    try:
        out = board(pico, "send(P.SETCURRENT, 'B', 55)\nrun(20)\nprint('state', core.disabled, core.hal.faults)")
    finally:
        devices.driver_faults(echo=True)
    disabled, faults = out.split("state", 1)[1].split()
    assert (disabled, int(faults) >= 1) == ("False", True)  # no crash, the failure counted
    assert "TMC2209" in out.split("state", 1)[0], out


@pytest.mark.parametrize("fault, message", [
    ({"driver_faults": {"badCrc": 1}}, "TMC2209 reply: CRC"),
    ({"driver_faults": {"silent": 1}}, "no reply to a read of register 0x06"),
    ({"encoder_faults": {"nack": 1}}, "OSError"),
])
def test_a_device_fault_at_boot_disables_the_joint_with_a_message(joint, fault, message) -> None:
    pico, devices, _, _ = joint
    (kind, args), = fault.items()
    getattr(devices, kind)(**args)
    out = board(pico, "make()\nrun(100)\nprint('state', core.disabled, core.ready, core.flags)")
    assert "motor fault, joint disabled until reset" in out and message in out, out
    assert out.split("state", 1)[1].split() == ["True", "True", str(0x0C | 0x08)]
    assert not devices.state()["driver"]["enabled"]  # ENN high: the bridges are off
