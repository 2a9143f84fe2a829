"""Motion-safety benchmark: the real joint firmware on the simulated arm, in virtual time.

`make bench-safety` runs the full scenario matrix and prints one `name value` line per figure;
`tests/test_bench_safety.py` runs a reduced matrix. Scenarios (each on a freshly booted joint with
the arm's mechanics, firmware.sim.mechanics, and the shipped J1-J4 configuration of default.toml):

* collision: joint x motor speed (10 rpm .. the joint's top speed) x obstacle (rigid stop block, soft)
  x payload (none, the joint's corner) x noise (nominal, harsh: encoder noise, harmonic error, ISR
  skips; as5600: the Pico backend's 12-bit encoder) x stall detector ("original", "tracking"). The obstacle stands a little ahead of the link
  at cruise; latency is from the first contact of the link to the STALL flag, split (figures not
  named by issue 11) into the time until the obstacle first overpowers the motor (its first pole
  slip: mechanics) and from there to STALL (the detector).
* false stalls: unobstructed moves at the configured limits (long moves, reversals, a streamed
  velocity trajectory at 50 Hz, a crawl of three motor turns each way at 10 rpm), per joint x
  payload x noise x detector: any STALL counts.
* homing: HOME with the shipped parameters into the joint's end stop, per joint x payload x noise x
  stop; J2 with a payload first freewheels as it does after boot. Success = homed within the time
  limit; false homed = "homed" with the reported position off the truth by more than the joint's
  mechanical homing error bound; the homed error is |reported - true| position, motor degrees. A
  HOME at a sensitivity within the noise floor must be refused (ERROR, LASTERROR reason, nothing
  started): that is its success, also counted as safety.homing_refused.
* deadman: the host falls silent while the joint moves (velocity, velocity after SETCURRENT 0 /
  SETHOLDCURRENT 0 / DISABLECLOSEDLOOP, positioning, homing, orientation check), with the original
  host's frames and with our host's watchdog (WATCHDOG register, when the firmware has it). An
  escape: the rotor still turns 3 s after the last frame where the joint must stop (velocity modes
  always; every mode once a watchdog is set). Stop start: last frame to the first drop of the
  driver's ramp speed, read every 0.1 ms.

Detector selection: `JointController.set_stall_detector(mode)` when the firmware has it, else the
per-joint config key stall.detector; a firmware with neither has only "original" (safety.* = nan).

The chip's costs (clock stretching, main-loop period) are the repository's table
(firmware/joint/sim/chip_costs.json); `--scl-scale F` scales every clock stretching time by F and
`--loop-jitter-us U` makes each main-loop iteration up to U us late, to show that the figures do not
hang on one table (bench/derive_safety.py derives on such variants).
"""

from __future__ import annotations

import math
import multiprocessing
import os
import pathlib
import statistics
import sys
import time
from dataclasses import dataclass
from typing import Iterable

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "firmware")]

from joint.config import schema as joint_config  # noqa: E402
from joint.core.supervise import DETECTOR_NAMES as DETECTORS  # noqa: E402
from joint.motion.hal import MAGNET_OK, MAGNET_WEAK  # noqa: E402
from joint.spec import protocol as P  # noqa: E402
from joint.sim import mechanics as M  # noqa: E402
from joint.sim.bus import SimJointBus, default_costs  # noqa: E402
from joint.sim.clock import VirtualClock  # noqa: E402
from joint.sim.joint import SimJoint, shipped_config  # noqa: E402
from joint.sim.stepper import SimStepper  # noqa: E402

import contact_bounds  # noqa: E402 -- bench/, beside this file
import encoder_errors  # noqa: E402
import sim_reference  # noqa: E402

JOINTS = ("J1", "J2", "J3", "J4")
# Shipped configuration (host/bioscara/data/default.toml), motor side: reduction magnitude,
# current %, stall threshold, max acceleration (joint units/s^2), max velocity, homing
# (speed byte rpm, threshold, current %).
CONFIG = {
    "J1": {"n": 35.0, "current": 20, "stall": 6, "acc": 2.0, "vel": 1.0, "home": (10, 30, 15)},
    "J2": {"n": 2 * math.pi / 0.004, "current": 8, "stall": 12, "acc": 0.2, "vel": 0.03, "home": (45, 50, 30)},
    "J3": {"n": 24.0, "current": 20, "stall": 6, "acc": 14.0, "vel": 5.0, "home": (11, 25, 10)},
    "J4": {"n": 12.0, "current": 20, "stall": 6, "acc": 30.0, "vel": 10.0, "home": (11, 30, 10)},
}
PAYLOAD = {"J1": 0.2, "J2": 1.0, "J3": 0.2, "J4": 0.2}  # kg: the corner (J2: enough to back-drive)
TRAVEL = {"J1": 2.0, "J2": 0.1, "J3": 2.0, "J4": 2.0}  # joint units of an unobstructed move
SPEEDS = (10.0, 30.0, 60.0, 120.0, 250.0)
# The free motion: long moves to these fractions of TRAVEL in turn (from 0), and a streamed sine
# (amplitude a fraction of the top speed, Hz) that ends in steps to +-top.
MOVE_FRACTIONS = (1.0, -1.0, 0.1, 0.0)
STREAM = (0.6, 0.7)
CRAWL_TURNS = 3  # and a crawl at SPEEDS[0], this many motor turns each way
NAN = float("nan")
NOISES = ("nominal", "harsh", "as5600")
CONTACT_NOISES = ("nominal", "harsh")
# Seeds of the contact matrix: none of them is a seed bench/derive_safety.py derives on.
CONTACT_SEEDS = (11, 12, 13, 14, 15)
CALIBRATED_HARMONICS = 0.1  # the encoder's harmonic error left after calibration (issue 20)
TRANSIENT_S = 0.5  # s after first contact: ISO/TS 15066's transient phase of a clamping contact
CHIP = None  # the bus's cost table (None: the repository's); main() sets a perturbed one


def top_rpm(joint: str) -> float:
    c = CONFIG[joint]
    return c["vel"] * c["n"] * 60.0 / (2 * math.pi)


def speeds(joint: str) -> list[float]:
    top = top_rpm(joint)
    return [s for s in SPEEDS if s < top * 0.97] + [math.floor(top)]


def move_span_deg(joint: str) -> float:
    """Motor degrees of TRAVEL[joint]."""
    return math.degrees(TRAVEL[joint] * CONFIG[joint]["n"])


def motion_set(joint: str) -> dict[str, set]:
    """What the bench runs on `joint`, as bench/derive_safety.py's motion_set describes what it
    derives on (the two must not meet, tests/test_derive_held_out.py): velocity steps (rpm, the
    collisions' and contacts' speeds and the stream's steps to +-top), moves ((from, to) motor
    degrees, rounded to 0.1), streams ((amplitude fraction, Hz)), payloads (kg) and seeds."""
    top = top_rpm(joint)
    span = move_span_deg(joint)
    targets = [round(span * f, 1) for f in (0.0,) + MOVE_FRACTIONS]
    return {"speeds": {round(v, 1) for v in speeds(joint)} | {round(top, 1)},
            "moves": set(zip(targets, targets[1:])), "streams": {STREAM},
            "payloads": {0.0, PAYLOAD[joint]}, "seeds": {1, *CONTACT_SEEDS}}


class Rig:
    """One joint: firmware on the arm's mechanics, a host that polls PING every `poll_s`."""

    def __init__(self, joint: str, detector: str = "original", payload_kg: float = 0.0, noise: str = "nominal",
                 seed: int = 1, low_deg: float | None = None, high_deg: float | None = None,
                 weak_magnet: bool = False, harmonics: float = 1.0) -> None:
        self.name = joint
        self.clock = VirtualClock()
        # noise: "nominal" | "harsh" (TLE5012B) | "as5600" (the Pico backend's 12-bit encoder);
        # harmonics: the fraction of the encoder's harmonic error left (0.1: what calibration leaves)
        encoder = "as5600" if noise == "as5600" else "tle5012b"
        kwargs = M.stepper_kwargs(joint, payload_kg, "nominal" if noise == "as5600" else noise, encoder)
        kwargs["enc_harmonics"] = tuple(harmonics * a for a in kwargs["enc_harmonics"])
        self.stepper = SimStepper(self.clock, seed=seed, **kwargs)
        if weak_magnet:
            # The AS5600 says so in its STATUS (the HOME refuses at once); the TLE5012B-modelled
            # encoder's status is not read: its weak magnet meets the noise check alone.
            self.stepper.weaken_magnet(reports=MAGNET_WEAK if encoder == "as5600" else MAGNET_OK)
        self.stepper.set_end_stops(low_deg, high_deg)
        # The shipped per-joint config (its stall and homing constants), on the simulated motor.
        cfg = shipped_config(joint)
        assert cfg.valid, cfg.errors
        if detector != "original" and not self._config_detector(cfg, detector):
            raise LookupError(detector)
        self.lines: list[str] = []
        self.joint = SimJoint(cfg, self.clock, self.stepper, write=self.lines.append)
        core = self.joint.core
        if hasattr(core, "set_stall_detector"):
            core.set_stall_detector(detector)
        self.bus = SimJointBus(self.clock, (self.joint,), chip=CHIP)
        self.addr = cfg.address
        self.last_frame_us = 0
        assert self.bus.boot(), "joint did not boot"
        self._slips = self.stepper.slipped_periods()
        self.slip_us: int | None = None  # when the rotor last slipped a pole (run() watches)

    @staticmethod
    def _config_detector(cfg: joint_config.JointConfig, detector: str) -> bool:
        stall_keys = dict(joint_config.SCHEMA)["stall"]
        if any(spec[0] == "detector" for spec in stall_keys):
            cfg.stall.detector = detector
            return True
        return False

    @property
    def flags(self) -> int:
        return self.joint.core.flags

    def _transfer(self, data: bytes, read_len: int) -> bytes:
        reply = self.bus.transfer(self.addr, data, read_len)
        self.last_frame_us = self.clock.now_us
        return reply

    def command(self, name: str, *values: float) -> int:
        reg = P.register(name)
        return self._transfer(bytes([reg.addr]) + reg.encode(*values), 1)[0]

    def ping(self) -> int:
        reg = P.register("PING")
        return self._transfer(bytes([reg.addr]), reg.rsize + 1)[-1]

    def read(self, name: str) -> float:
        reg = P.register(name)
        reply = self._transfer(bytes([reg.addr]), reg.rsize + 1)
        return reg.decode(reply[:-1])[0]

    def enable(self, watchdog_ms: int | None = None, stall_threshold: int | None = None) -> None:
        c = CONFIG[self.name]
        self.command("SETUP", c["current"], c["current"], 0, 0)
        if stall_threshold == 0:
            self.command("DISABLESTALLGUARD", 0)
        else:
            self.command("ENABLESTALLGUARD", c["stall"] if stall_threshold is None else stall_threshold)
        self.command("SETMAXACCELERATION", math.degrees(c["acc"] * c["n"]))
        self.command("SETMAXVELOCITY", math.degrees(c["vel"] * c["n"]))
        if watchdog_ms is not None and P.BY_NAME.get("WATCHDOG") is not None:
            self.command("WATCHDOG", watchdog_ms)

    def run(self, seconds: float, poll_s: float | None = 0.02, step_s: float = 0.001, until=None) -> bool:
        """Advance in `step_s` steps, polling like a host every `poll_s` (None: silent host);
        True as soon as until() holds."""
        t_end = self.clock.now_us + int(seconds * 1e6)
        next_poll = self.clock.now_us
        while self.clock.now_us < t_end:
            self.bus.sleep(step_s)
            slips = self.stepper.slipped_periods()
            if slips != self._slips:
                self._slips = slips
                self.slip_us = self.clock.now_us
            if poll_s is not None and self.clock.now_us >= next_poll:
                self.ping()
                next_poll = self.clock.now_us + int(poll_s * 1e6)
            if until is not None and until():
                return True
        return False


def slipped(rig: Rig) -> bool:
    """The rotor lost steps (pole slips) within the last 300 ms: a STALL then is a true one."""
    return rig.slip_us is not None and rig.clock.now_us - rig.slip_us < 300_000


def _available(detector: str) -> bool:
    try:
        Rig("J4", detector)
    except LookupError:
        return False
    return True


# ---- scenarios ----------------------------------------------------------------------------------

@dataclass(frozen=True)
class Collision:
    joint: str
    rpm: float
    stop: str
    payload: bool
    noise: str
    detector: str
    seed: int = 1
    stall_threshold: int | None = None  # None: the shipped one; 0 turns stall detection off


def collision(s: Collision) -> dict:
    rig = Rig(s.joint, s.detector, PAYLOAD[s.joint] if s.payload else 0.0, s.noise, s.seed)
    rig.enable(stall_threshold=s.stall_threshold)
    c = CONFIG[s.joint]
    accel_rpm_s = math.degrees(c["acc"] * c["n"]) / 6.0
    rig.command("SETRPM", s.rpm)
    cruise = s.rpm / accel_rpm_s + 0.4
    if rig.run(cruise, until=lambda: rig.flags & P.FLAG_STALL):
        # Before the obstacle: a false stall, unless the motor really lost steps accelerating.
        return {"detected": False, "latency_ms": NAN, "false_stall": not slipped(rig), "lost_steps": slipped(rig)}
    m = rig.stepper
    # The obstacle: 20 ms of travel (at least 1 degree) ahead of the link.
    ahead = max(1.0, s.rpm * 6.0 * 0.02)
    wall = m.load_angle() + ahead
    k, damping = M.stop_stiffness(s.joint, s.stop, PAYLOAD[s.joint] if s.payload else 0.0)
    m.add_obstacle(wall, 1, stiffness=k, damping=damping)
    contact = [None]
    slip = [None]  # the first pole slip after the contact: the motor overpowered
    slips = m.slipped_periods()
    pressed = [0.0]  # the deepest the link has pressed into the obstacle, motor degrees

    def done() -> bool:
        m.update()  # the mechanics up to now (the simulator integrates lazily, at main-loop ticks)
        pressed[0] = max(pressed[0], m.load_angle() - wall)
        if contact[0] is None and m.load_angle() >= wall:
            contact[0] = rig.clock.now_us
        if contact[0] is not None and slip[0] is None and m.slipped_periods() != slips:
            slip[0] = rig.clock.now_us
        return bool(rig.flags & P.FLAG_STALL)
    hit = rig.run(ahead / (s.rpm * 6.0) + 3.0, step_s=0.0005, until=done)
    if contact[0] is None:
        return {"detected": False, "latency_ms": NAN, "false_stall": hit and not slipped(rig),
                "lost_steps": slipped(rig)}
    slip_ms = NAN if slip[0] is None else (slip[0] - contact[0]) / 1000.0
    # The obstacle's largest spring force at the contact until STALL (or the run's end).
    force = M.contact_force_n(s.joint, k * math.radians(pressed[0]))
    if not hit:
        return {"detected": False, "latency_ms": NAN, "false_stall": False, "lost_steps": False, "slip_ms": slip_ms,
                "force_n": force}
    return {"detected": True, "latency_ms": (rig.clock.now_us - contact[0]) / 1000.0, "false_stall": False,
            "lost_steps": False, "slip_ms": slip_ms, "force_n": force}


@dataclass(frozen=True)
class Contact:
    """A body region (ISO/TS 15066) met by the joint at `rpm` motor speed, in `direction`."""
    joint: str
    rpm: float
    direction: int  # +1 / -1: the motion's (and the obstacle's) side
    payload: bool
    noise: str  # "nominal" | "harsh" (TLE5012B)
    region: str  # a key of mechanics.ISO_TS_15066
    seed: int = CONTACT_SEEDS[0]
    detector: str = "tracking"
    harmonics: float = 1.0  # the fraction of the encoder's harmonic error left (Rig)


def contact(s: Contact) -> dict:
    """The largest force the region takes (N, its spring at the gripper; J2: at the nut) until the
    joint stops pushing: its STALL and 0.3 s for the stop, or, undetected, 0.3 s past the motor's
    first pole slip (the most it can push), or a cap of 1.5 x the quasi-static time to pull-out.

    ISO/TS 15066 judges a clamping contact in two phases: its transient peak (the first
    TRANSIENT_S after contact, the link's momentum) against twice the region's limit, the force
    after it (the motor pushing) against the quasi-static limit; `over` says whether either was
    exceeded, `force_n` is the largest force at any time."""
    payload = PAYLOAD[s.joint] if s.payload else 0.0
    rig = Rig(s.joint, s.detector, payload, s.noise, s.seed, harmonics=s.harmonics)
    rig.enable()
    c = CONFIG[s.joint]
    accel_rpm_s = math.degrees(c["acc"] * c["n"]) / 6.0
    rig.command("SETRPM", s.direction * s.rpm)
    limit = M.ISO_TS_15066[s.region][1]
    if rig.run(s.rpm / accel_rpm_s + 0.4, until=lambda: rig.flags & P.FLAG_STALL):
        return {"force_n": 0.0, "limit_n": limit, "detected": False, "false_stall": not slipped(rig),
                "lost_steps": slipped(rig)}
    m = rig.stepper
    ahead = max(1.0, s.rpm * 6.0 * 0.02)
    wall = m.load_angle() + s.direction * ahead
    k, damping = M.stop_stiffness(s.joint, s.region, payload)
    m.add_obstacle(wall, s.direction, stiffness=k, damping=damping)
    slips = m.slipped_periods()
    seen = {"peak": 0.0, "transient": 0.0, "quasi": 0.0, "stall_us": None, "slip_us": None, "contact_us": None,
            "stall_n": NAN}

    def done() -> bool:
        m.update()
        now = rig.clock.now_us
        depth = (m.load_angle() - wall) * s.direction
        force = M.contact_force_n(s.joint, k * math.radians(depth)) if depth > 0.0 else 0.0
        seen["peak"] = max(seen["peak"], force)
        if seen["contact_us"] is None and depth > 0.0:
            seen["contact_us"] = now
        if seen["contact_us"] is not None:
            phase = "transient" if now - seen["contact_us"] <= TRANSIENT_S * 1e6 else "quasi"
            seen[phase] = max(seen[phase], force)
        if seen["contact_us"] is not None and seen["slip_us"] is None and m.slipped_periods() != slips:
            seen["slip_us"] = now
        if seen["stall_us"] is None and rig.flags & P.FLAG_STALL:
            seen["stall_us"] = now
            seen["stall_n"] = force
        end = min(t for t in (seen["stall_us"], seen["slip_us"]) if t is not None) if (
            seen["stall_us"] is not None or seen["slip_us"] is not None) else None
        return end is not None and now - end >= 300_000
    # Time for the region's spring to reach the motor's pull-out (quasi-static, gravity helping).
    jl, k_t, _, _, gravity, _, _, _ = M._reflect(s.joint, payload)
    w = s.rpm * 2 * math.pi / 60.0
    to_pullout_s = (contact_bounds.t_max(s.joint, w) + abs(gravity)) / (w / (1.0 / k_t + 1.0 / k))
    rig.run(ahead / (s.rpm * 6.0) + 1.5 * to_pullout_s + 1.0, step_s=0.0005, until=done)
    over = seen["transient"] > 2.0 * limit or seen["quasi"] > limit
    return {"force_n": seen["peak"], "transient_n": seen["transient"], "quasi_static_n": seen["quasi"],
            "limit_n": limit, "over": over, "detected": seen["stall_us"] is not None,
            "stall_force_n": seen["stall_n"], "false_stall": False, "lost_steps": False}


@dataclass(frozen=True)
class FreeMove:
    joint: str
    kind: str  # "moves" | "stream" | "crawl"
    payload: bool
    noise: str
    detector: str
    seed: int = 1


def free_move(s: FreeMove) -> dict:
    """Unobstructed motion at the configured limits; the number of STALL flags raised."""
    rig = Rig(s.joint, s.detector, PAYLOAD[s.joint] if s.payload else 0.0, s.noise, s.seed)
    rig.enable()
    c = CONFIG[s.joint]
    stalls = 0
    lost = 0
    core = rig.joint.core
    # The detector's largest reading over its threshold in free motion; for the tracking detector
    # the smallest over its last `confirm` samples (what it stalls on), a sample told from the next
    # by its (lag, threshold) changing.
    worst = 0.0
    recent: list[tuple[int, int]] = []
    # The slow-contact detector's (where the joint has one): its excess over its limit, the
    # smallest over its last `confirm` samples (one a millisecond here: a 5 ms sample is read 5 times).
    load_worst = 0.0
    load_recent: list[int] = []

    def stalled() -> bool:
        nonlocal stalls, lost, worst, load_worst
        track = core.track
        if s.detector == "tracking" and track.threshold > 0:
            if not recent or recent[-1] != (track.lag, track.threshold):
                recent.append((track.lag, track.threshold))
                del recent[:-track.confirm]
                worst = max(worst, min(lag / thr for lag, thr in recent))
        if s.detector == "tracking" and core.load is not None:
            load_recent.append(core.load.excess)
            del load_recent[:-core.load.confirm]
            load_worst = max(load_worst, min(load_recent) / core.load.limit)
        elif s.detector == "original" and core.stall.threshold > 0:
            worst = max(worst, core.stall.filtered / core.stall.threshold)
        if not rig.flags & P.FLAG_STALL:
            return False
        if slipped(rig):
            lost += 1
        else:
            stalls += 1
        return True
    if s.kind == "crawl":
        # CRAWL_TURNS motor turns each way at the slowest speed: the slow-contact detector judges
        # the load angle against its baseline from the second turn on.
        for rpm in (SPEEDS[0], -SPEEDS[0], 0.0):
            rig.command("SETRPM", rpm)
            if rig.run(CRAWL_TURNS * 60.0 / SPEEDS[0] + 0.3 if rpm else 0.5, until=stalled):
                break
    elif s.kind == "moves":
        span = move_span_deg(s.joint)
        t_move = span / math.degrees(c["vel"] * c["n"]) + 2 * c["vel"] / c["acc"] + 0.5
        for target in (span * f for f in MOVE_FRACTIONS):
            rig.command("MOVETOANGLE", target)
            if rig.run(t_move, until=stalled):
                rig.command("SETUP", c["current"], c["current"], 0, 0)
                rig.command("ENABLESTALLGUARD", c["stall"])
    else:
        # A streamed velocity trajectory as a trajectory controller sends it: 50 Hz setpoints of a
        # sine (STREAM: 60 % of the top speed, 0.7 Hz), then an abrupt reversal at full speed.
        top = top_rpm(s.joint)
        amplitude, hz = STREAM
        for i in range(150):
            rig.command("SETRPM", amplitude * top * math.sin(2 * math.pi * hz * i * 0.02))
            if rig.run(0.02, poll_s=None, until=stalled):
                break
        if not stalls + lost:
            for rpm in (top, -top, 0.0):
                rig.command("SETRPM", rpm)
                if rig.run(2 * top / (math.degrees(c["acc"] * c["n"]) / 6.0) + 0.3, until=stalled):
                    break
    return {"false_stalls": stalls, "lost_steps": lost, "worst_ratio": worst, "load_worst_ratio": load_worst}


@dataclass(frozen=True)
class Homing:
    joint: str
    payload: bool
    noise: str
    stop: str
    seed: int = 1
    sensitivity: int | None = None  # None: the shipped homing threshold
    overhaul_nm: float = 0.0  # extra load torque on the link (N*m, motor side; negative: down on J2)
    payload_kg: float | None = None  # None: PAYLOAD[joint] if payload else 0
    weak_magnet: bool = False  # encoder noise x 20 and a 20 deg / 10 deg harmonic error
    stop_in_reach: bool = True  # False: no stop within the joint's homing travel limit


def homing(s: Homing) -> dict:
    """HOME into the end stop. success: homed within the mechanical error bound, or (a weak magnet,
    an overhauling load, no stop, a sensitivity never reached) ended not homed; false_homed: homed
    off the truth; push_s: from the link's first contact with the stop to the driver's ramp
    speed reaching 0; running_s: from HOME to the end of BUSY."""
    payload = s.payload_kg if s.payload_kg is not None else (PAYLOAD[s.joint] if s.payload else 0.0)
    speed, threshold, current = CONFIG[s.joint]["home"]
    if s.sensitivity is not None:
        threshold = s.sensitivity
    # The stop 180 motor degrees (J2: 720, 2 mm) below the link, which homes in the negative
    # direction: about 3 s of travel at the homing speed; or, out of reach, beyond the travel limit.
    distance = 720.0 if s.joint == "J2" else 180.0
    travel_limit = _homing_travel_deg(s.joint)
    if not s.stop_in_reach:
        distance = 1.5 * travel_limit
    rig = Rig(s.joint, "original", payload, s.noise, s.seed, low_deg=-distance, weak_magnet=s.weak_magnet)
    k, damping = M.stop_stiffness(s.joint, s.stop, payload)
    m = rig.stepper
    m.clear_obstacles()
    m.add_obstacle(-distance, -1, stiffness=k, damping=damping)
    m.set_load_torque(-s.overhaul_nm)
    rig.run(1.0, poll_s=0.1)  # a host that connects a second after boot: the joint freewheels
    rig.enable()
    start_us = rig.clock.now_us
    reply = rig.command("HOME", 0, speed, threshold, current)
    if reply & P.FLAG_ERROR and rig.read("LASTERROR") == P.REJECT_HOMING_SENSITIVITY:
        # A sensitivity within the joint's noise floor is refused (issue 11): the right outcome,
        # provided nothing started (not busy, still not homed).
        right = not rig.flags & P.FLAG_BUSY and bool(rig.flags & P.FLAG_NOTHOMED)
        return {"success": right, "false_homed": False, "error_deg": NAN, "refused": True,
                "push_s": NAN, "running_s": 0.0}
    seen = {"contact": None, "stopped": None}

    def watch() -> bool:
        m.update()
        now = rig.clock.now_us
        if seen["contact"] is None and m.load_angle() <= -distance:
            seen["contact"] = now
        if seen["contact"] is not None and seen["stopped"] is None and m.driver_rpm() == 0.0:
            seen["stopped"] = now
        return not rig.flags & P.FLAG_BUSY
    limit = (travel_limit if not s.stop_in_reach else distance) / (speed * 6.0) * 3 + 10.0
    finished = rig.run(limit, poll_s=0.05, until=watch)
    running_s = (rig.clock.now_us - start_us) / 1e6
    push_s = NAN
    if seen["contact"] is not None:
        end = seen["stopped"] if seen["stopped"] is not None else rig.clock.now_us
        push_s = (end - seen["contact"]) / 1e6
    homed = finished and not rig.flags & P.FLAG_NOTHOMED
    # Refusing is right for a soft obstacle, a weak magnet, a link the homing current cannot catch
    # (an overhauling load), a sensitivity never reached, no stop in reach.
    expect_home = (s.stop == "rigid" and s.stop_in_reach and not s.weak_magnet and not s.overhaul_nm
                   and s.payload_kg is None and (s.sensitivity is None or s.sensitivity <= 100))
    if not homed:
        outcome = int(rig.read("HOMINGRESULT")) if P.BY_NAME.get("HOMINGRESULT") is not None else 0
        rig.command("STOP", 0)
        return {"success": finished and not expect_home, "false_homed": False, "error_deg": NAN,
                "push_s": push_s, "running_s": running_s, "outcome": outcome,
                "travel_deg": abs(m.load_angle())}
    rig.run(0.5, poll_s=0.05)
    reported = rig.read("ANGLEMOVED")
    true = rig.stepper.load_angle() + distance  # link displacement from its stop
    error = abs(reported - true)
    if s.noise == "as5600":  # same harmonic error figures, plus one 12-bit count
        bound = M.homing_error_bound_deg(s.joint, current, "nominal", payload) + 360.0 / 4096
    else:
        bound = M.homing_error_bound_deg(s.joint, current, s.noise, payload)
    # Homed where no stop could be touched (none in reach, a weak magnet's error) is false too.
    false = error > bound or not s.stop_in_reach or s.weak_magnet
    return {"success": not false, "false_homed": false, "error_deg": error, "push_s": push_s,
            "running_s": running_s}


def _homing_travel_deg(joint: str) -> float:
    """The joint's configured homing travel limit, motor degrees (firmware/joint/config)."""
    cfg = joint_config.load(str(ROOT / "firmware" / "joint" / "config" / f"{joint}.json"))
    return cfg.homing.max_travel_deg


@dataclass(frozen=True)
class Deadman:
    joint: str
    state: str  # velocity | setcurrent0 | setholdcurrent0 | disableclosedloop | position | homing | orientation
    host: str  # "original" (no watchdog) | "ours" (watchdog at the deadman time)
    seed: int = 1


VELOCITY_STATES = ("velocity", "setcurrent0", "setholdcurrent0", "disableclosedloop")
DEADMAN_STATES = VELOCITY_STATES + ("position", "homing", "orientation")


def deadman(s: Deadman) -> dict:
    rig = Rig(s.joint, "original", 0.0, "nominal", s.seed)
    rig.enable(watchdog_ms=50 if s.host == "ours" else None)
    rpm = min(60.0, top_rpm(s.joint))
    if s.state == "position":
        rig.command("MOVETOANGLE", 36000.0)
    elif s.state == "homing":
        rig.command("HOME", 0, CONFIG[s.joint]["home"][0], 100, CONFIG[s.joint]["home"][2])
    elif s.state == "orientation":
        rig.command("CHECKORIENTATION", 90.0)
    else:
        rig.command("SETRPM", rpm)
    rig.run(1.0 if s.state != "orientation" else 0.7)
    if s.state == "setcurrent0":
        rig.command("SETCURRENT", 0)
    elif s.state == "setholdcurrent0":
        rig.command("SETHOLDCURRENT", 0)
    elif s.state == "disableclosedloop":
        rig.command("DISABLECLOSEDLOOP", 0)
    last = rig.last_frame_us
    m = rig.stepper
    v0 = abs(m.driver_rpm())
    start = [None]

    def watch() -> bool:
        m.update()  # the driver's ramp is its own (TMC5130): read it now, not at the next main loop
        if start[0] is None and abs(m.driver_rpm()) < v0 - 0.2:
            start[0] = rig.clock.now_us
        return False
    rig.run(0.1, poll_s=None, step_s=0.0001, until=watch)  # the stop start to 0.1 ms
    rig.run(2.4, poll_s=None, until=watch)
    a = m.rotor_angle()
    rig.run(0.5, poll_s=None)
    moving = abs(m.rotor_angle() - a) > 1.0
    must_stop = s.state in VELOCITY_STATES or s.host == "ours"
    # The orientation check changes speed by itself: no stop start to see there.
    timed = must_stop and not moving and start[0] is not None and s.state != "orientation"
    stop_ms = (start[0] - last) / 1000.0 if timed else NAN
    return {"escape": must_stop and moving, "stop_start_ms": stop_ms}


# ---- the matrix ----------------------------------------------------------------------------------

def matrix(full: bool = True, detectors: Iterable[str] = DETECTORS, every_seed: bool = False) -> list:
    """The full matrix, or the reduced one `make test` runs (a few corners of each kind); the
    full one ends with the contacts in newtons (`contacts`)."""
    dets = list(detectors)
    scenarios: list = []
    if not full:
        for det in dets:
            scenarios += [Collision("J1", 120.0, "rigid", False, "nominal", det),
                          Collision("J1", 10.0, "rigid", False, "harsh", det),
                          Collision("J2", 120.0, "soft", True, "harsh", det),
                          FreeMove("J4", "stream", True, "harsh", det),
                          # J2's long moves with harsh noise: where too small a derivation set
                          # left the constants without margin (a false stall per move set).
                          FreeMove("J2", "moves", False, "harsh", det)]
        scenarios += [Homing("J1", False, "nominal", "rigid"), Homing("J2", True, "harsh", "rigid"),
                      Homing("J1", False, "harsh", "rigid", sensitivity=15),
                      Deadman("J1", "velocity", "original"), Deadman("J1", "setcurrent0", "ours"),
                      Deadman("J2", "position", "ours"),
                      Contact("J2", 250.0, 1, True, "harsh", "hand"), Contact("J3", 120.0, -1, False, "nominal", "abdomen")]
        # J2's slow soft contact, raw and calibrated encoder, and the crawl its detector judges.
        scenarios += [Contact("J2", 10.0, 1, True, "harsh", "abdomen", harmonics=h)
                      for h in (1.0, CALIBRATED_HARMONICS)]
        scenarios += [FreeMove("J2", "crawl", True, "harsh", det) for det in dets if det == "tracking"]
        return scenarios
    for joint in JOINTS:
        for rpm in speeds(joint):
            for stop in ("rigid", "soft"):
                for payload in (False, True):
                    for noise in NOISES:
                        for det in dets:
                            scenarios.append(Collision(joint, rpm, stop, payload, noise, det))
        for kind in ("moves", "stream", "crawl"):
            for payload in (False, True):
                for noise in NOISES:
                    for det in dets:
                        scenarios.append(FreeMove(joint, kind, payload, noise, det))
        for payload in (False, True):
            for noise in NOISES:
                for stop in ("rigid", "soft"):
                    scenarios.append(Homing(joint, payload, noise, stop))
        # A sensitivity at the noise floor (the original lies there; it should be refused).
        scenarios.append(Homing(joint, False, "harsh", "rigid", sensitivity=15))
        # Homing that must not lie or push on (issue 20): sensitivities the closed loop never lets
        # the PID error reach, a weak magnet, no stop within the travel limit.
        scenarios += [Homing(joint, False, "nominal", "rigid", sensitivity=sens) for sens in (200, 255)]
        scenarios += [Homing(joint, False, noise, "rigid", weak_magnet=True) for noise in ("nominal", "as5600")]
        scenarios.append(Homing(joint, False, "nominal", "rigid", stop_in_reach=False))
        for state in DEADMAN_STATES:
            for host in ("original", "ours"):
                scenarios.append(Deadman(joint, state, host))
    # J2 freewheeling under an overhauling load, then homing up against it.
    scenarios += [Homing("J2", True, "nominal", "rigid", overhaul_nm=nm) for nm in (0.01, 0.02, 0.03)]
    scenarios += [Homing("J2", True, "harsh", "rigid", payload_kg=kg) for kg in (2.0, 3.0)]
    return scenarios + contacts(every_seed)


def contacts(every_seed: bool = False) -> list[Contact]:
    """Every joint x speed (10 rpm .. top) x direction x payload x encoder noise x body region,
    each on one of CONTACT_SEEDS in turn (every_seed: on all five)."""
    out: list[Contact] = []
    i = 0
    for joint in JOINTS:
        for rpm in speeds(joint):
            for direction in (1, -1):
                for payload in (False, True):
                    for noise in CONTACT_NOISES:
                        for region in M.ISO_TS_15066:
                            seeds = CONTACT_SEEDS if every_seed else (CONTACT_SEEDS[i % len(CONTACT_SEEDS)],)
                            i += 1
                            out += [Contact(joint, rpm, direction, payload, noise, region, seed) for seed in seeds]
    # J2's slow soft contact again with 10 % of the encoder's harmonic error, what calibration
    # leaves: the slow-contact detector's figure with and without it.
    out += [Contact("J2", 10.0, direction, payload, noise, "abdomen", seed, harmonics=CALIBRATED_HARMONICS)
            for direction in (1, -1) for payload in (False, True) for noise in CONTACT_NOISES
            for seed in (CONTACT_SEEDS if every_seed else CONTACT_SEEDS[:1])]
    return out


RUNNERS = {Collision: collision, FreeMove: free_move, Homing: homing, Deadman: deadman, Contact: contact}


def run_one(s) -> tuple:
    return s, RUNNERS[type(s)](s)


def run_all(scenarios: list, processes: int = 1) -> list[tuple]:
    if processes > 1:
        with multiprocessing.get_context("fork").Pool(processes) as pool:
            return pool.map(run_one, scenarios, chunksize=1)
    return [run_one(s) for s in scenarios]


def _fmt(x: float) -> str:
    return "nan" if x != x else ("%.4g" % x)


def figures(results: list[tuple], available: Iterable[str]) -> list[tuple[str, float]]:
    """`name value` figures: per detector (safety.original.* and safety.* for the new one), then
    homing and deadman (not detector-dependent)."""
    avail = set(available)
    out: list[tuple[str, float]] = []
    for det, prefix in (("original", "safety.original."), ("tracking", "safety.")):
        runs = [(s, r) for s, r in results if isinstance(s, Collision) and s.detector == det]
        # A run whose motor lost steps before reaching the obstacle is no collision: it counts in
        # lost_steps_unobstructed only.
        col = [(s, r) for s, r in runs if not r["lost_steps"]]
        free = [(s, r) for s, r in results if isinstance(s, FreeMove) and s.detector == det]
        if det not in avail or not runs:
            for name in ("collision_detect_rate", "collision_detect_rate.j1", "collision_detect_rate.j2",
                         "collision_detect_rate.j3", "collision_detect_rate.j4", "collision_detect_rate.rigid",
                         "collision_detect_rate.soft", "collision_latency_ms_median",
                         "collision_latency_ms_max", "collision_latency_ms_median.rigid",
                         "collision_latency_ms_max.rigid", "collision_latency_ms_median.soft",
                         "collision_latency_ms_max.soft", "collision_overpowered_ms_max",
                         "collision_latency_ms_after_slip_max", "collision_never_overpowered",
                         "soft_contact_force_n_max", "soft_contact_force_n_max.undetected",
                         "soft_contacts_over_iso_limit", "false_stalls", "free_motion_worst_fraction_of_threshold",
                         "lost_steps_unobstructed"):
                out.append((prefix + name, NAN))
            continue
        out.append((prefix + "collision_detect_rate", sum(r["detected"] for _, r in col) / len(col)))
        for joint in JOINTS:
            mine = [r for s, r in col if s.joint == joint]
            out.append((prefix + "collision_detect_rate." + joint.lower(),
                        sum(r["detected"] for r in mine) / len(mine) if mine else NAN))
        for stop in ("rigid", "soft"):  # not names of issue 11: the rate per obstacle kind
            mine = [r for s, r in col if s.stop == stop]
            out.append((prefix + "collision_detect_rate." + stop,
                        sum(r["detected"] for r in mine) / len(mine) if mine else NAN))
        for suffix, kinds in (("", ("rigid", "soft")), (".rigid", ("rigid",)), (".soft", ("soft",))):
            lat = [r["latency_ms"] for s, r in col if r["detected"] and s.stop in kinds]
            out.append((prefix + "collision_latency_ms_median" + suffix, statistics.median(lat) if lat else NAN))
            out.append((prefix + "collision_latency_ms_max" + suffix, max(lat) if lat else NAN))
        # Not names of issue 11: where the latency goes. overpowered: contact to the motor's first
        # pole slip (the obstacle's force reached the motor's torque: mechanics, the same for any
        # detector); after_slip: that slip to STALL (the detector's own share); never_overpowered:
        # collisions in which the motor kept synchronism for the whole run (no lost step to see).
        slips = [(r["slip_ms"], r["latency_ms"]) for _, r in col if r.get("slip_ms", NAN) == r.get("slip_ms", NAN)]
        out.append((prefix + "collision_overpowered_ms_max", max(a for a, _ in slips) if slips else NAN))
        after = [b - a for a, b in slips if b == b]
        out.append((prefix + "collision_latency_ms_after_slip_max", max(after) if after else NAN))
        out.append((prefix + "collision_never_overpowered", sum(1 for _, r in col if "slip_ms" in r
                                                               and r["slip_ms"] != r["slip_ms"] and not r["detected"])))
        # Not names of issue 11: the soft obstacle's force (N at the gripper) when STALL came, the
        # largest reached in the runs that never saw one, and how many soft contacts went past
        # ISO/TS 15066's quasi-static limit for the abdomen (110 N) either way.
        soft = [r for s, r in col if s.stop == "soft" and "force_n" in r]
        caught = [r["force_n"] for r in soft if r["detected"]]
        missed = [r["force_n"] for r in soft if not r["detected"]]
        out.append((prefix + "soft_contact_force_n_max", max(caught) if caught else NAN))
        out.append((prefix + "soft_contact_force_n_max.undetected", max(missed) if missed else NAN))
        out.append((prefix + "soft_contacts_over_iso_limit", sum(r["force_n"] > M.ISO_ABDOMEN_N for r in soft)))
        out.append((prefix + "false_stalls", sum(r["false_stalls"] for _, r in free)
                    + sum(r["false_stall"] for _, r in col)))
        # Issue 20: the detector's worst reading in free motion on this matrix, as a fraction of its
        # threshold (1: a false stall), with constants derived on other seeds.
        ratios = [r["worst_ratio"] for _, r in free if "worst_ratio" in r]
        out.append((prefix + "free_motion_worst_fraction_of_threshold", max(ratios) if ratios else NAN))
        if det == "tracking":  # the slow-contact detector beside it (load_angle.py; J2)
            loads = [r["load_worst_ratio"] for _, r in free if "load_worst_ratio" in r]
            out.append(("safety.load_angle_free_motion_worst_fraction_of_limit", max(loads) if loads else NAN))
        # Not a name of issue 11: moves at the shipped limits where the motor itself lost steps.
        out.append((prefix + "lost_steps_unobstructed", sum(r["lost_steps"] for _, r in free)
                    + sum(r["lost_steps"] for _, r in runs)))
    hom = [r for s, r in results if isinstance(s, Homing)]
    if hom:
        out.append(("safety.homing_success_rate", sum(r["success"] for r in hom) / len(hom)))
        # Not a name of issue 11: HOMEs refused for a sensitivity within the noise floor (counted
        # as successes above when the joint refused them cleanly).
        out.append(("safety.homing_refused", sum(bool(r.get("refused")) for r in hom)))
        out.append(("safety.homing_false_homed", sum(r["false_homed"] for r in hom)))
        errs = [r["error_deg"] for r in hom if r["error_deg"] == r["error_deg"]]
        out.append(("safety.homed_error_deg_max", max(errs) if errs else NAN))
        # Not names of issue 11: how long a HOME pushed on the stop after the link touched it, and
        # how long one without a stop in reach ran, against the time its travel limit takes.
        pushes = [r["push_s"] for r in hom if r.get("push_s", NAN) == r.get("push_s", NAN)]
        out.append(("safety.homing_push_s_max", max(pushes) if pushes else NAN))
        lost = [(s, r) for s, r in results if isinstance(s, Homing) and not s.stop_in_reach]
        out.append(("safety.homing_no_stop_s_max", max(r["running_s"] for _, r in lost) if lost else NAN))
        out.append(("safety.homing_no_stop_travel_ratio_max",
                    max(r.get("travel_deg", NAN) / _homing_travel_deg(s.joint) for s, r in lost) if lost else NAN))
    touched = [(s, r) for s, r in results if isinstance(s, Contact) and not r["lost_steps"]]
    calibrated = [(s, r) for s, r in touched if s.harmonics != 1.0]
    touched = [(s, r) for s, r in touched if s.harmonics == 1.0]
    if touched:
        # ISO/TS 15066 in newtons: the largest force each region took from each joint until it
        # stopped pushing, and how many contacts went past the region's quasi-static limit.
        for region in M.ISO_TS_15066:
            for joint in JOINTS:
                forces = [r["force_n"] for s, r in touched if s.region == region and s.joint == joint]
                out.append((f"safety.contact_force_n_max.{region}.{joint.lower()}", max(forces) if forces else NAN))
        out.append(("safety.contacts_over_limit", sum(r["over"] for _, r in touched)))
        # Stricter, for reference: contacts whose force ever passed the quasi-static limit.
        out.append(("safety.contacts_over_quasi_static_limit_at_any_time",
                    sum(r["force_n"] > r["limit_n"] for _, r in touched)))
        # J2's soft contact at 10 rpm: the most it pushed after the transient phase, and the force
        # when the joint said STALL (nan if it never did: then it pushed until the pole slip), with
        # the encoder's harmonic error as shipped and with what calibration leaves of it.
        for suffix, runs in (("", touched), (".harmonics_10pct", calibrated)):
            slow = [r for s, r in runs if s.joint == "J2" and s.rpm == 10.0 and s.region == "abdomen"]
            out.append(("safety.j2_soft_contact_10rpm_force_n_max" + suffix,
                        max(r["quasi_static_n"] for r in slow) if slow else NAN))
            at_stall = [r["stall_force_n"] for r in slow]
            out.append(("safety.j2_soft_contact_10rpm_stall_force_n_max" + suffix,
                        max(at_stall) if at_stall and all(f == f for f in at_stall) else NAN))
        out.append(("safety.contacts_false_stalls", sum(r["false_stall"] for s, r in results if isinstance(s, Contact))))
        out.append(("safety.contacts_lost_steps_before_contact",
                    sum(r["lost_steps"] for s, r in results if isinstance(s, Contact))))
    for joint in JOINTS:
        out.append((f"safety.pullout_force_n.{joint.lower()}", pullout_force_n(joint)))
    dm = [r for s, r in results if isinstance(s, Deadman)]
    if dm:
        out.append(("safety.deadman_escapes", sum(r["escape"] for r in dm)))
        starts = [r["stop_start_ms"] for r in dm if r["stop_start_ms"] == r["stop_start_ms"]]
        out.append(("safety.deadman_stop_start_ms_max", max(starts) if starts else NAN))
    return out


def pullout_force_n(joint: str) -> float:
    """The most the joint can push at its shipped drive current (N at the gripper; J2 at the nut,
    downward with the payload's and the link's weight): the motor's torque at rest, quasi-static
    (contact_bounds.t_max), less the friction it must overcome; with gravity on J2."""
    jl, _, _, friction, gravity, _, _, _ = M._reflect(joint, PAYLOAD[joint])
    torque = contact_bounds.t_max(joint, 0.0) + abs(gravity) - friction
    return M.contact_force_n(joint, torque)


def details(results: list[tuple]) -> list[str]:
    """Per-scenario lines for the misses (stderr), to see where a figure comes from."""
    lines = []
    for s, r in results:
        bad = ((isinstance(s, Collision) and not r["detected"])
               or (isinstance(s, Contact) and (r.get("over") or r["false_stall"] or r["lost_steps"]))
               or (isinstance(s, FreeMove) and (r["false_stalls"] or r["lost_steps"]))
               or (isinstance(s, Homing) and not r["success"]) or (isinstance(s, Deadman) and r["escape"]))
        if bad:
            lines.append(f"# {s} -> {r}")
    return lines


def _option(argv: list[str], name: str, default: float) -> float:
    if name not in argv:
        return default
    i = argv.index(name)
    try:
        return float(argv[i + 1])
    except (IndexError, ValueError):
        raise SystemExit(f"{name} needs a number") from None


def main(argv: list[str]) -> int:
    global CHIP
    full = "--reduced" not in argv
    verbose = "-v" in argv
    scl, jitter = _option(argv, "--scl-scale", 1.0), _option(argv, "--loop-jitter-us", 0.0)
    if scl != 1.0 or jitter:
        if scl < 0 or jitter < 0:
            raise SystemExit("--scl-scale and --loop-jitter-us must not be negative")
        CHIP = default_costs().perturbed(scl_scale=scl, loop_jitter_us=jitter)
        print(f"# chip cost table: {CHIP.source}", file=sys.stderr)
    avail = [d for d in DETECTORS if _available(d)]
    scenarios = matrix(full, avail, every_seed="--every-seed" in argv)
    t0 = time.perf_counter()
    results = run_all(scenarios, processes=min(2, os.cpu_count() or 1))
    for name, value in figures(results, avail):
        print(name, _fmt(value), flush=True)
    # The simulator these figures rest on, against an independent solution of its equations.
    print("safety.sim_reference_error_pct", _fmt(sim_reference.error_pct()), flush=True)
    # Each joint's encoder error over a motor turn, before and after `bioscara calibrate`.
    for name, value in encoder_errors.figures():
        print(name, _fmt(value), flush=True)
    print(f"# {len(scenarios)} scenarios in {time.perf_counter() - t0:.0f} s; detectors: {', '.join(avail)}",
          file=sys.stderr)
    if verbose:
        for line in details(results):
            print(line, file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
