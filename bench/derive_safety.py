"""Derive each joint's tracking stall-detector constants and its quick-stop deceleration from the
simulated arm's mechanics (firmware/joint/sim/mechanics.py), so they come from a procedure, not a guess.

Stall detector (tracking.py: stalled when lag > base + min(|field speed| * tau, cap), the lag taken
net of `slope` per ustep of travel): run the real firmware through unobstructed motion at the
joint's configured acceleration and record every sample the firmware's detector is fed (field and
encoder usteps). The motion set is held out from the benchmark's (bench/safety.py; `overlap`
lists what both run, and must be empty): velocity steps to 13 rpm .. 98 % of the top speed and back
through reversals, a crawl of CRAWL_TURNS motor turns each way at 13 rpm, short position moves at
top speed, long moves to other fractions of the bench's travel (polled as a host polls them), two
streamed sines of other amplitudes and frequencies than the bench's (a new velocity every 20 ms)
and full-speed reversals at 98 % of the top. It runs with
nominal and harsh TLE5012B noise and the Pico backend's AS5600, with 5 % and 120 % of the bench's
payload corner (the bench runs 0 and 100 %), on SEEDS (the bench: 1 and 11..15), and on every cost
table of TABLES: the measured one
(firmware/joint/sim/chip_costs.json) and variants with the chip's clock stretching x0.3 and x1.5
and with loop-period jitter (each main-loop iteration up to 500 us late) -- the bus timing moves
the instants at which the detector samples, and the constants must not depend on it.

Then replay the recording through the detector for each slope, confirm (CONFIRMS samples) and tau
(0..20 ms). The slope is at least SLOPE_MIN, the largest rate at which the datasheet's harmonic
error (1x and 2x per revolution, harsh corner) can change the reading per ustep turned: the error
then cannot build up over a long move, whichever phases of the revolution the samples happen to
fall on. Base and cap cover MARGIN x every lag seen held over `confirm` samples in a row (and at
least MIN_BASE), and the set kept is the one that detects a blocked rotor soonest at 10 and 30 rpm
(the lag of a blocked rotor grows by 1 - slope per ustep of field, then `confirm` samples). Phases
in which the motor really lost position are reported and left out (the detector is right to stop
those). The largest free lag is printed per cost table: the margin left on each.

Slow-contact detector (load_angle.py, where a joint's config turns it on: J2): the same
recordings replayed through it; load_limit is the smallest that covers MARGIN x the largest free
excess held over LOAD_CONFIRM samples with the clip it sets (5/4 of the limit).

Quick stop: the largest deceleration (full steps/s^2, at most the driver's 11636) from which the
joint stops at top speed without losing position (no pole slip in the simulator),
times 0.8.

    python bench/derive_safety.py            # print the constants
    python bench/derive_safety.py --write    # and store them in firmware/joint/config/J*.json
    python bench/derive_safety.py J2         # only the joints named
"""

import json
import math
import multiprocessing
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [os.path.join(HERE, "..", "firmware"), os.path.join(HERE, "..", "firmware", "tests")]

import numpy as np  # noqa: E402
import safety as bench  # noqa: E402 -- the benchmark's matrix, to stay out of it
from harness import SimRig  # noqa: E402
from joint.motion.fixed import STEPS_Q, to_q  # noqa: E402
from joint.sim import mechanics  # noqa: E402
from joint.sim.chip import ChipCosts  # noqa: E402
from joint.detect.load_angle import LoadAngleDetector  # noqa: E402
from joint.detect.tracking import TrackingDetector  # noqa: E402

# The arm's configured motion (host/bioscara/data/default.toml) on the motor side.
JOINTS = {  # top speed rpm, acceleration motor deg/s^2, drive current %, stall sensitivity
    "J1": (334.0, 4011.0, 20, 6),
    "J2": (450.0, 18000.0, 8, 12),
    "J3": (1146.0, 19251.0, 20, 6),
    "J4": (1146.0, 20626.0, 20, 6),
}
# Held out (issue 20): the derivation's motion, payloads and seeds are none of those bench/safety.py
# runs (bench.motion_set; main() refuses to derive if they meet, tests/test_derive_held_out.py
# checks), so the bench judges the constants on motion they were not fitted to.
STEP_SPEEDS = (13.0, 40.0, 90.0, 200.0)  # rpm; the bench's are 10, 30, 60, 120, 250 and its top
TOP_FRACTION = 0.98  # the fastest step: the bench runs floor(top) and top
CRAWL_TURNS = 2.5  # motor turns at the slowest step speed, each way (the bench: 3 at 10 rpm)
SHORT_MOVE_S = 0.5  # short moves of this many seconds at top speed, out and back
LONG_MOVE_FRACTIONS = (0.7, -0.45, 0.25, 0.0)  # of the bench's long move (its: 1, -1, 0.1, 0)
STREAMS = ((0.5, 1.0 / 1.5), (0.8, 0.45))  # (amplitude x top speed, Hz); the bench's: (0.6, 0.7)
PAYLOAD_FRACTIONS = (0.05, 1.2)  # of the bench's payload corner (it runs 0 and 1x)
SEEDS = (2, 3, 4)  # the bench: 1, its contacts 11..15
MEASURED = ChipCosts.load()
TABLES = {  # name: the chip's costs (clock stretching per transaction, main-loop period)
    "measured": MEASURED,
    "SCL x0.3": MEASURED.perturbed(scl_scale=0.3),
    "SCL x1.5": MEASURED.perturbed(scl_scale=1.5),
    "loop jitter 500 us": MEASURED.perturbed(loop_jitter_us=500.0),
}
MARGIN = 2.0  # on every free lag: room for seeds, phases and timings the derivation did not run
SATURATE = False  # cap the speed allowance at the largest lag seen (lower thresholds, less margin)
MIN_BASE = 128  # half a full step: room for what the simulator leaves out (detent torque ripple)
SAMPLE_MS = 5
CONFIRMS = (2, 3, 4)  # samples in a row over the threshold: the search's choices
WINDOW = 64  # samples: at 10 rpm the lag can grow by 2700 usteps within it
SLOPE_MAX = 32  # /256 usteps of encoder error per ustep of travel
# The harmonic error a1*sin(x + p1) + a2*sin(2x + p2) (deg) changes the reading by at most
# (a1 + 2*a2) * pi/180 per unit of rotor angle: Q8, rounded up, over every encoder and noise corner.
SLOPE_MIN = max(int(math.ceil((a1 + 2.0 * a2) * math.pi / 180.0 * 256.0))
                for enc in mechanics.ENCODERS.values() for a1, a2 in enc["harmonics"].values())
DRIVER_MAX_DECEL = 11636.0
# The slow-contact detector (load_angle.py): confirm and clip are fixed (the clip 5/4 of the limit:
# the excess of a contact already past the limit when first judged still crosses it within 13
# samples, and a sample's spike adds at most 5/32 of it), the limit covers MARGIN x every free
# excess held over LOAD_CONFIRM samples, and at least LOAD_MIN_LIMIT.
LOAD_CONFIRM = 3
LOAD_MIN_LIMIT = 16


def load_clip(limit):
    return limit + limit // 4


class _Recorder(TrackingDetector):
    """The firmware's detector, never stopping, keeping what it is fed (None: a reset)."""

    def __init__(self):
        super().__init__(10 ** 8, 0, WINDOW, 1, SAMPLE_MS)
        self.fed = []

    def update(self, field, encoder):
        self.fed.append((field, encoder))
        return super().update(field, encoder)

    def reset(self):
        self.fed.append(None)
        super().reset()


class _LoadRecorder(LoadAngleDetector):
    """The slow-contact detector, never stopping, keeping the driver's speed it is fed (the field
    and encoder are _Recorder's: the core feeds both the same sample)."""

    def __init__(self):
        super().__init__(10 ** 8, 1, 10 ** 8)
        self.speeds = []

    def update(self, field, encoder, speed):
        self.speeds.append(speed)
        return super().update(field, encoder, speed)


def _rig(joint, noise, seed, payload_kg=0.0, table="measured"):
    """noise: "nominal" | "harsh" (TLE5012B) | "as5600" (the Pico backend's 12-bit encoder);
    table: a name of TABLES."""
    encoder = "as5600" if noise == "as5600" else "tle5012b"
    kwargs = mechanics.stepper_kwargs(joint, payload_kg, "nominal" if noise == "as5600" else noise, encoder)
    rig = SimRig(joint, seed=seed, chip=TABLES[table], **kwargs)
    top, accel, current, sensitivity = JOINTS[joint]
    rig.enable(current=current, sensitivity=sensitivity, accel_deg=accel, vel_deg=top * 6.0)
    core = rig.joint.core
    core.set_stall_detector("tracking")
    core.track = _Recorder()  # record, never stop
    core.load = _LoadRecorder()
    return rig


def _record(rig, seconds, out, losses, phase="", poll_ms=SAMPLE_MS):
    """Run `seconds` as one phase of the motion set, the host pinging every `poll_ms` (None:
    silent): `out` gets (first, end) of the samples the detector was fed in it, unless the motor
    lost position (slipped a pole) at any time in it (then `losses` gets the phase)."""
    core = rig.joint.core
    before = rig.stepper.slipped_periods()  # the simulator's own count of pole slips
    first = len(core.track.fed)
    t_end = rig.clock.now_us + int(seconds * 1e6)
    next_poll = rig.clock.now_us
    slipped = False
    while rig.clock.now_us < t_end:
        rig.bus.sleep(SAMPLE_MS / 1000.0)
        if poll_ms is not None and rig.clock.now_us >= next_poll:
            rig.ping()
            next_poll = rig.clock.now_us + poll_ms * 1000
        # Every sample: a rotor can slip a pole and slip back within one phase.
        slipped = slipped or rig.stepper.slipped_periods() != before
    if slipped:
        losses.append(phase)
        core.track.reset()  # the live detector would have stopped here: its history ends
        rig.command("SETUP", *JOINTS[rig.joint.cfg.joint][2:3] * 2, 0, 0)  # re-synchronise
        rig.command("ENABLESTALLGUARD", JOINTS[rig.joint.cfg.joint][3])
    else:
        out.append((first, len(core.track.fed)))


def step_speeds(joint):
    """The velocity steps of the derivation (rpm): STEP_SPEEDS below TOP_FRACTION of the top speed,
    then that fraction."""
    top = JOINTS[joint][0] * TOP_FRACTION
    return [rpm for rpm in STEP_SPEEDS if rpm < top] + [top]


def payloads(joint):
    return tuple(round(f * bench.PAYLOAD[joint], 3) for f in PAYLOAD_FRACTIONS)


def _move_targets(joint):
    """Motor degrees: the short moves at top speed, then the long ones (fractions of the bench's
    span), each from the previous target."""
    short = JOINTS[joint][0] * 6.0 * SHORT_MOVE_S
    span = bench.move_span_deg(joint)
    return [short, -short, 0.0] + [span * f for f in LONG_MOVE_FRACTIONS]


def motion_set(joint):
    """What the derivation runs on `joint`, in bench.motion_set's terms (the first move starts
    where the velocity steps left the rotor: from None)."""
    targets = [None] + [round(t, 1) for t in _move_targets(joint)]
    return {"speeds": {round(v, 1) for v in step_speeds(joint)},
            "moves": set(zip(targets, targets[1:])), "streams": set(STREAMS),
            "payloads": set(payloads(joint)), "seeds": set(SEEDS)}


def overlap(joint):
    """Whatever the derivation and the bench both run on `joint` ({} when held out)."""
    mine, theirs = motion_set(joint), bench.motion_set(joint)
    return {key: mine[key] & theirs[key] for key in mine if mine[key] & theirs[key]}


def free_motion(args):
    """args (joint, noise, seed, payload_kg, table) -> (what the detector was fed, the (first, end)
    sample ranges of the free phases, the phases in which the motor lost position) through the
    unobstructed motion set (held out from the bench's: motion_set)."""
    joint, noise, seed, payload_kg, table = args
    accel = JOINTS[joint][1]
    phases = []
    losses = []
    rig = _rig(joint, noise, seed, payload_kg, table)
    for rpm in step_speeds(joint):
        ramp = 2.0 * rpm * 6.0 / accel + 0.3
        rig.command("SETRPM", rpm)
        _record(rig, ramp, phases, losses, "to %g rpm" % rpm)
        rig.command("SETRPM", -rpm)  # a reversal at the configured acceleration
        _record(rig, ramp, phases, losses, "reversal at %g rpm" % rpm)
        rig.command("SETRPM", 0.0)
        _record(rig, ramp / 2.0, phases, losses, "stop from %g rpm" % rpm)
    crawl = step_speeds(joint)[0]  # long enough each way for the slow-contact detector to judge
    for rpm in (crawl, -crawl):
        rig.command("SETRPM", rpm)
        _record(rig, CRAWL_TURNS * 60.0 / crawl + 0.3, phases, losses, "crawl at %g rpm" % rpm, poll_ms=20)
    rig.command("SETRPM", 0.0)
    _record(rig, 0.5, phases, losses, "stop from the crawl")
    top = step_speeds(joint)[-1]
    c = bench.CONFIG[joint]
    t_short = 1.5 + 2.0 * JOINTS[joint][0] * 6.0 / accel
    t_long = bench.move_span_deg(joint) / math.degrees(c["vel"] * c["n"]) + 2 * c["vel"] / c["acc"] + 0.5
    for i, target in enumerate(_move_targets(joint)):  # the long ones polled as a host polls them
        rig.command("MOVETOANGLE", target)
        if i < 3:
            _record(rig, t_short, phases, losses, "move to %g deg" % target)
        else:
            _record(rig, t_long, phases, losses, "long move to %g deg" % target, poll_ms=20)
    for amplitude, hz in STREAMS:  # streamed trajectories: a new velocity every 20 ms
        for k in range(150):
            rig.command("SETRPM", amplitude * top * math.sin(2.0 * math.pi * hz * k * 0.02))
            _record(rig, 0.02, phases, losses, "streamed sine %g x top, %g Hz" % (amplitude, hz), poll_ms=None)
        rig.command("SETRPM", 0.0)
        _record(rig, 0.5, phases, losses, "stop")
    for rpm in (top, -top, 0.0):
        rig.command("SETRPM", rpm)
        _record(rig, 2.0 * top * 6.0 / accel + 0.3, phases, losses, "step to %g rpm" % rpm, poll_ms=20)
    core = rig.joint.core
    return core.track.fed, phases, losses, core.load.speeds


def replay(runs, slope):
    """(lag, |field usteps per sample|, judged) per sample of every run, replayed through the
    detector with `slope`: judged is 1 where the detector compared (the field moved) in a free
    phase, 0 elsewhere, and one 0 separates the runs. Each recording replays in one piece, as the
    firmware ran it."""
    lags, speeds, judged = [], [], []
    for fed, phases, _, _ in runs:
        free = bytearray(len(fed))
        for first, end in phases:
            free[first:end] = b"\x01" * (end - first)
        det = TrackingDetector(10 ** 8, 0, WINDOW, 1, SAMPLE_MS, slope_q8=slope)
        for i, sample in enumerate(fed):
            if sample is None:
                det.reset()
                lags.append(0)
                speeds.append(0)
                judged.append(0)
                continue
            det.update(*sample)
            lags.append(det.lag)
            speeds.append(abs(det.speed))
            judged.append(1 if det.speed and free[i] else 0)
        lags.append(0)
        speeds.append(0)
        judged.append(0)
    return np.array(lags, float), np.array(speeds, float), np.array(judged, bool)


def held(trace, confirm):
    """(lag, speed) of every run of `confirm` judged samples in a row, by its smallest lag and
    speed: the detector trips only if all of them are over the threshold (ringing of the
    transmission cannot make them all high)."""
    lags, speeds, judged = trace
    if len(lags) < confirm:
        return np.zeros(0), np.zeros(0)
    window = np.lib.stride_tricks.sliding_window_view
    ok = window(judged, confirm).all(axis=1)
    return window(lags, confirm).min(axis=1)[ok], window(speeds, confirm).min(axis=1)[ok]


def fit(runs):
    """(base, tau_ms, cap, slope_q8, confirm, largest free lag) detecting a blocked rotor soonest at
    10 and 30 rpm while covering MARGIN x every free sample: for each slope, confirm and tau, base is
    what the slow samples need beyond their speed allowance, cap what the largest lag needs beyond
    base; the time to detect is the samples the lag of a blocked rotor, growing by (1 - slope) x the
    field's travel per sample, takes to pass the threshold, plus `confirm` samples."""
    best = None
    for slope in range(SLOPE_MIN, SLOPE_MAX + 1, 2):
        trace = replay(runs, slope)
        for confirm in CONFIRMS:
            lag, speed = held(trace, confirm)
            worst = MARGIN * float(lag.max())
            for tau in range(0, 21):
                base = max(MIN_BASE, int(np.floor((MARGIN * lag - speed * tau / SAMPLE_MS).max())) + 1)
                cap = max(0, int(worst - base) + 1) if SATURATE else 1000000
                cost = 0.0
                for rpm in (10.0, 30.0):
                    per_sample = rpm * 51200 / 60.0 * SAMPLE_MS / 1000.0
                    threshold = base + min(cap, per_sample * tau / SAMPLE_MS)
                    cost += threshold / ((1.0 - slope / 256.0) * per_sample) + confirm
                if best is None or cost < best[0]:
                    best = (cost, base, tau, cap, slope, confirm, worst / MARGIN)
    return best[1:]


def largest_load_excess(runs, clip, confirm=LOAD_CONFIRM):
    """The largest excess of the slow-contact detector (clipping each sample at `clip`) held over
    `confirm` samples in a row in the free phases (usteps), every recording replayed in one piece
    as the firmware ran it."""
    worst = 0
    for fed, phases, _, speeds in runs:
        free = bytearray(len(fed))
        for first, end in phases:
            free[first:end] = b"\x01" * (end - first)
        det = LoadAngleDetector(10 ** 8, 1, clip)
        recent = []
        judged = 0
        for i, sample in enumerate(fed):
            if sample is None:
                det.reset()
                recent.clear()
                continue
            det.update(sample[0], sample[1], speeds[judged])
            judged += 1
            recent.append(det.excess if free[i] else -(10 ** 9))
            del recent[:-confirm]
            if len(recent) == confirm:
                worst = max(worst, min(recent))
    return worst


def load_limit(runs):
    """(limit, clip, largest free excess) of the slow-contact detector: the smallest limit that
    covers MARGIN x the largest free excess with the clip it sets (load_clip)."""
    limit = LOAD_MIN_LIMIT
    while True:
        worst = largest_load_excess(runs, load_clip(limit))
        if limit > MARGIN * worst:
            return limit, load_clip(limit), worst
        limit = int(MARGIN * worst) + 1


def keeps_position(joint, decel):
    top, _, _, _ = JOINTS[joint]
    rig = _rig(joint, "nominal", SEEDS[0])
    rig.joint.core.stop_deceleration = to_q(decel, STEPS_Q)  # the core's unit: full steps/s^2 Q4
    rig.command("WATCHDOG", 20)
    rig.command("SETRPM", top)
    rig.poll(1.0 + top * 6.0 / JOINTS[joint][1], period=0.01)
    before = rig.stepper.slipped_periods()
    rig.bus.sleep(0.6)  # silence: the deadman's quick stop
    return rig.stepper.slipped_periods() == before


def stop_deceleration(joint):
    decel = DRIVER_MAX_DECEL
    while decel > 100.0 and not keeps_position(joint, decel):
        decel *= 0.8
    return round(0.8 * decel)


def cases(joint):
    """Every (joint, noise, seed, payload_kg, table) the derivation runs."""
    return [(joint, noise, seed, payload, table) for noise in ("nominal", "harsh", "as5600") for seed in SEEDS
            for payload in payloads(joint) for table in TABLES]


def largest_lag(runs, slope, confirm):
    lag, _ = held(replay(runs, slope), confirm)
    return int(lag.max()) if len(lag) else 0


def main(argv):
    results = {}
    losses = {}
    processes = 1 if "-j1" in argv else min(2, os.cpu_count() or 1)
    for joint in JOINTS:
        if overlap(joint):
            sys.exit("%s: the derivation runs what the bench runs: %s" % (joint, overlap(joint)))
    chosen = [joint for joint in JOINTS if joint in argv] or list(JOINTS)
    for joint in chosen:
        todo = cases(joint)
        if processes > 1:
            with multiprocessing.get_context("fork").Pool(processes) as pool:
                runs = pool.map(free_motion, todo, chunksize=1)
        else:
            runs = [free_motion(case) for case in todo]
        losses[joint] = sorted({phase for _, _, lost, _ in runs for phase in lost})
        base, tau, cap, slope, confirm, worst = fit(runs)
        decel = stop_deceleration(joint)
        results[joint] = {"track_base": base, "track_tau_ms": tau, "track_cap": cap, "track_slope_q8": slope,
                          "track_confirm": confirm, "stop_deceleration": float(decel)}
        print("%s: %d runs, %d free phases, largest free lag %d usteps net of the slope -> track_base %d, "
              "track_tau_ms %d, track_cap %d, track_slope_q8 %d, track_confirm %d; stop_deceleration %d "
              "full steps/s^2" % (joint, len(runs), sum(len(p) for _, p, _, _ in runs), worst, base, tau, cap, slope,
                                  confirm, decel))
        limit, clip, excess = load_limit(runs)
        print("%s: slow-contact detector: largest free excess %d usteps over %d samples -> load_limit %d, "
              "load_clip %d" % (joint, excess, LOAD_CONFIRM, limit, clip))
        results[joint]["load"] = (limit, clip)
        for table in TABLES:  # the margin left on each cost table (the speed allowance aside)
            mine = [run for case, run in zip(todo, runs) if case[4] == table]
            print("  %s: largest free lag %d usteps (base %d)" % (table, largest_lag(mine, slope, confirm), base))
    for joint in chosen:
        if losses[joint]:
            print("%s lost position in %d kinds of phase (real stalls, excluded): %s"
                  % (joint, len(losses[joint]), ", ".join(losses[joint])))
    if "--write" in argv:
        for joint, values in results.items():
            path = os.path.join(HERE, "..", "firmware", "joint", "config", joint + ".json")
            with open(path) as f:
                cfg = json.load(f)
            cfg["stop_deceleration"] = values["stop_deceleration"]
            for key in ("track_base", "track_tau_ms", "track_cap", "track_slope_q8"):
                cfg["stall"][key] = values[key]
            cfg["stall"]["track_confirm"] = values["track_confirm"]
            cfg["stall"]["track_window"] = WINDOW
            cfg["stall"]["track_sample_ms"] = SAMPLE_MS
            if cfg["stall"].get("load_limit"):  # the joints that need it (J2: docs/safety.md)
                cfg["stall"]["load_limit"], cfg["stall"]["load_clip"] = values["load"]
                cfg["stall"]["load_confirm"] = LOAD_CONFIRM
            tmp = path + ".tmp"
            with open(tmp, "w") as f:
                json.dump(cfg, f, indent=2)
                f.write("\n")
            os.replace(tmp, path)
            print("wrote", os.path.relpath(path))


if __name__ == "__main__":
    main(sys.argv[1:])
