"""Derive each joint's tracking stall-detector constants and its quick-stop deceleration from the
simulated arm's mechanics (firmware/joint/sim/mechanics.py), so they come from a procedure, not a guess.

Stall detector (tracking.py: stalled when lag > base + min(|field speed| * tau, cap), the lag taken
net of `slope` per ustep of travel): run the real firmware through unobstructed motion at the
joint's configured acceleration -- velocity steps to 10 rpm .. top speed and back through
reversals, position moves at top speed, a streamed trajectory -- with nominal and harsh TLE5012B
noise and the Pico backend's AS5600 (the shipped configs drive a Pico), without and with the
joint's payload corner, on seeds the benchmark does not use, and record every sample the
firmware's detector is fed (field and encoder usteps). Then replay the recording through the
detector for each slope (0..SLOPE_MAX/256), confirm (CONFIRMS samples) and tau (0..20 ms): base and
cap cover MARGIN x every lag seen held over `confirm` samples in a row, and the set kept is the one
that detects a blocked rotor soonest at 10 and 30 rpm (the lag of a blocked rotor grows by
1 - slope per ustep of field, then `confirm` samples). Phases in which the motor really lost position are reported and left
out (the detector is right to stop those).

Quick stop: the largest deceleration (full steps/s^2, at most the driver's 11636) from which the
joint stops at top speed without losing position (no pole slip in the simulator),
times 0.8.

    python bench/derive_safety.py            # print the constants
    python bench/derive_safety.py --write    # and store them in firmware/joint/configs/J*.json
"""

import json
import math
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [os.path.join(HERE, "..", "firmware"), os.path.join(HERE, "..", "firmware", "tests")]

from harness import SimRig  # noqa: E402
from joint.fixed import STEPS_Q, to_q  # noqa: E402
from joint.sim import mechanics  # noqa: E402
from joint.tracking import TrackingDetector  # noqa: E402

# The arm's configured motion (host/bioscara/data/default.toml) on the motor side.
JOINTS = {  # top speed rpm, acceleration motor deg/s^2, drive current %, stall sensitivity
    "J1": (334.0, 4011.0, 20, 6),
    "J2": (450.0, 18000.0, 40, 12),
    "J3": (1146.0, 19251.0, 20, 6),
    "J4": (1146.0, 20626.0, 20, 6),
}
# The payload corner of each joint (kg; J2: enough to back-drive the screw), as bench/safety.py.
PAYLOAD = {"J1": 0.2, "J2": 1.0, "J3": 0.2, "J4": 0.2}
# Simulator seeds of the derivation; bench/safety.py runs seed 1, so it checks the constants on
# noise they were not derived from.
SEEDS = (2, 3)
MARGIN = 2.0
SATURATE = False  # cap the speed allowance at the largest lag seen (lower thresholds, less margin)
MIN_BASE = 128  # half a full step: room for what the simulator leaves out (detent torque ripple)
SAMPLE_MS = 5
CONFIRMS = (2, 3, 4)  # samples in a row over the threshold: the search's choices
WINDOW = 64  # samples: at 10 rpm the lag can grow by 2700 usteps within it
SLOPE_MAX = 32  # /256 usteps of encoder error per ustep of travel (the datasheet harmonics need ~10)
DRIVER_MAX_DECEL = 11636.0


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


def _rig(joint, noise, seed, payload_kg=0.0):
    """noise: "nominal" | "harsh" (TLE5012B) | "as5600" (the Pico backend's 12-bit encoder)."""
    encoder = "as5600" if noise == "as5600" else "tle5012b"
    kwargs = mechanics.stepper_kwargs(joint, payload_kg, "nominal" if noise == "as5600" else noise, encoder)
    rig = SimRig(joint, seed=seed, **kwargs)
    top, accel, current, sensitivity = JOINTS[joint]
    rig.enable(current=current, sensitivity=sensitivity, accel_deg=accel, vel_deg=top * 6.0)
    core = rig.joint.core
    core.set_stall_detector("tracking")
    core.track = _Recorder()  # record, never stop
    return rig


LOSSES = []  # (joint, phase): the motor lost position there, a real stall, not free motion


def _record(rig, seconds, out, phase=""):
    """Run `seconds` as one phase of the motion set: `out` gets (first, end) of the samples the
    detector was fed in it, unless the motor lost position (slipped a pole) at any time in it."""
    core = rig.joint.core
    before = rig.stepper.slipped_periods()  # the simulator's own count of pole slips
    first = len(core.track.fed)
    t_end = rig.clock.seconds() + seconds
    slipped = False
    while rig.clock.seconds() < t_end:
        rig.bus.sleep(SAMPLE_MS / 1000.0)
        rig.ping()
        # Every sample: a rotor can slip a pole and slip back within one phase.
        slipped = slipped or rig.stepper.slipped_periods() != before
    if slipped:
        LOSSES.append((rig.joint.cfg.joint, phase))
        core.track.reset()  # the live detector would have stopped here: its history ends
        rig.command("SETUP", *JOINTS[rig.joint.cfg.joint][2:3] * 2, 0, 0)  # re-synchronise
        rig.command("ENABLESTALLGUARD", JOINTS[rig.joint.cfg.joint][3])
    else:
        out.append((first, len(core.track.fed)))


def free_motion(joint, noise, seed, payload_kg=0.0):
    """(what the detector was fed, the (first, end) sample ranges of the free phases) through the
    unobstructed motion set."""
    top, accel, _, _ = JOINTS[joint]
    phases = []
    rig = _rig(joint, noise, seed, payload_kg)
    for rpm in (10.0, 30.0, 100.0, 300.0, top):
        rpm = min(rpm, top)
        ramp = 2.0 * rpm * 6.0 / accel + 0.3
        rig.command("SETRPM", rpm)
        _record(rig, ramp, phases, "to %g rpm" % rpm)
        rig.command("SETRPM", -rpm)  # a reversal at the configured acceleration
        _record(rig, ramp, phases, "reversal at %g rpm" % rpm)
        rig.command("SETRPM", 0.0)
        _record(rig, ramp / 2.0, phases, "stop from %g rpm" % rpm)
    short = top * 6.0 * 0.5
    for target in (short, -short, 0.0):
        rig.command("MOVETOANGLE", target)
        _record(rig, 1.5 + 2.0 * top * 6.0 / accel, phases, "move to %g deg" % target)
    for k in range(150):  # a streamed trajectory: a new velocity every 20 ms
        rig.command("SETRPM", 0.5 * top * math.sin(2.0 * math.pi * k / 75.0))
        _record(rig, 0.02, phases, "streamed trajectory")
    rig.command("SETRPM", 0.0)
    return rig.joint.core.track.fed, phases


def replay(runs, slope, confirm):
    """(lag, |field usteps per sample|) of every run of `confirm` samples in a row of the free phases
    with which the detector with `slope` could trip, by its smallest lag and speed (it trips only
    if all of them are over the threshold; ringing of the transmission cannot make them all high).
    Each recording replays in one piece, as the firmware ran it."""
    out = []
    for fed, phases in runs:
        free = bytearray(len(fed))
        for first, end in phases:
            free[first:end] = b"\x01" * (end - first)
        det = TrackingDetector(10 ** 8, 0, WINDOW, confirm, SAMPLE_MS, slope_q8=slope)
        seen = []
        for i, sample in enumerate(fed):
            if sample is None:
                det.reset()
                seen = []
                continue
            det.update(*sample)
            if det.speed and free[i]:
                seen.append((det.lag, abs(det.speed)))
            else:
                seen = []
            if len(seen) >= confirm:
                run = seen[-confirm:]
                out.append((min(lag for lag, _ in run), min(speed for _, speed in run)))
    return out


def fit(runs):
    """(base, tau_ms, cap, slope_q8, confirm, largest free lag) detecting a blocked rotor soonest at
    10 and 30 rpm while covering MARGIN x every free sample: for each slope, confirm and tau, base is
    what the slow samples need beyond their speed allowance, cap what the largest lag needs beyond
    base; the time to detect is the samples the lag of a blocked rotor, growing by (1 - slope) x the
    field's travel per sample, takes to pass the threshold, plus `confirm` samples."""
    best = None
    for confirm in CONFIRMS:
        for slope in range(0, SLOPE_MAX + 1, 2):
            samples = replay(runs, slope, confirm)
            worst = max(MARGIN * lag for lag, _ in samples)
            for tau in range(0, 21):
                base = max(MIN_BASE, max(int(MARGIN * lag - speed * tau / SAMPLE_MS) + 1 for lag, speed in samples))
                cap = max(0, int(worst - base) + 1) if SATURATE else 1000000
                cost = 0.0
                for rpm in (10.0, 30.0):
                    per_sample = rpm * 51200 / 60.0 * SAMPLE_MS / 1000.0
                    threshold = base + min(cap, per_sample * tau / SAMPLE_MS)
                    cost += threshold / ((1.0 - slope / 256.0) * per_sample) + confirm
                if best is None or cost < best[0]:
                    best = (cost, base, tau, cap, slope, confirm, worst / MARGIN)
    return best[1:]


def keeps_position(joint, decel):
    top, _, _, _ = JOINTS[joint]
    rig = _rig(joint, "nominal", 1)
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


def main(argv):
    results = {}
    for joint in JOINTS:
        runs = [free_motion(joint, noise, seed, payload) for noise in ("nominal", "harsh", "as5600")
                for seed in SEEDS for payload in (0.0, PAYLOAD[joint])]
        base, tau, cap, slope, confirm, worst = fit(runs)
        decel = stop_deceleration(joint)
        results[joint] = {"track_base": base, "track_tau_ms": tau, "track_cap": cap, "track_slope_q8": slope,
                          "track_confirm": confirm, "stop_deceleration": float(decel)}
        print("%s: %d free phases, largest free lag %d usteps net of the slope -> track_base %d, track_tau_ms %d, "
              "track_cap %d, track_slope_q8 %d, track_confirm %d; stop_deceleration %d full steps/s^2"
              % (joint, sum(len(p) for _, p in runs), worst, base, tau, cap, slope, confirm, decel))
    for joint in JOINTS:
        lost = [phase for j, phase in LOSSES if j == joint]
        if lost:
            print("%s lost position in %d phases (real stalls, excluded): %s"
                  % (joint, len(lost), ", ".join(sorted(set(lost)))))
    if "--write" in argv:
        for joint, values in results.items():
            path = os.path.join(HERE, "..", "firmware", "joint", "configs", joint + ".json")
            with open(path) as f:
                cfg = json.load(f)
            cfg["stop_deceleration"] = values["stop_deceleration"]
            for key in ("track_base", "track_tau_ms", "track_cap", "track_slope_q8"):
                cfg["stall"][key] = values[key]
            cfg["stall"]["track_confirm"] = values["track_confirm"]
            cfg["stall"]["track_window"] = WINDOW
            cfg["stall"]["track_sample_ms"] = SAMPLE_MS
            tmp = path + ".tmp"
            with open(tmp, "w") as f:
                json.dump(cfg, f, indent=2)
                f.write("\n")
            os.replace(tmp, path)
            print("wrote", os.path.relpath(path))


if __name__ == "__main__":
    main(sys.argv[1:])
