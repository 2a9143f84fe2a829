"""Derive each joint's tracking stall-detector constants and its quick-stop deceleration from the
simulated arm's mechanics (firmware/joint/sim/mechanics.py), so they come from a procedure, not a guess.

Stall detector (tracking.py: stalled when lag > base + min(|field speed| * tau, cap)): run the real
firmware through unobstructed motion at the joint's configured acceleration -- velocity steps to 10
rpm .. top speed and back through reversals, position moves at top speed, a streamed trajectory --
with nominal and harsh TLE5012B noise and the Pico backend's AS5600 (the shipped configs drive a
Pico), and record every sample's lag and field speed. tau is the value (0..20 ms) that gives the
lowest threshold at 10 and 30 rpm once base and cap cover MARGIN x every lag seen held over CONFIRM
samples in a row. Phases in which the motor really lost position are reported and left out (the
detector is right to stop those).

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

# The arm's configured motion (host/bioscara/data/default.toml) on the motor side.
JOINTS = {  # top speed rpm, acceleration motor deg/s^2, drive current %, stall sensitivity
    "J1": (334.0, 4011.0, 20, 6),
    "J2": (450.0, 18000.0, 40, 12),
    "J3": (1146.0, 19251.0, 20, 6),
    "J4": (1146.0, 20626.0, 20, 6),
}
MARGIN = 2.0
SATURATE = False  # cap the speed allowance at the largest lag seen (lower thresholds, less margin)
MIN_BASE = 48
SAMPLE_MS = 5
CONFIRM = 4
WINDOW = 64  # samples: at 10 rpm the lag can grow by 2700 usteps within it
DRIVER_MAX_DECEL = 11636.0


def _rig(joint, noise, seed):
    """noise: "nominal" | "harsh" (TLE5012B) | "as5600" (the Pico backend's 12-bit encoder)."""
    encoder = "as5600" if noise == "as5600" else "tle5012b"
    kwargs = mechanics.stepper_kwargs(joint, noise="nominal" if noise == "as5600" else noise, encoder=encoder)
    rig = SimRig(joint, seed=seed, **kwargs)
    top, accel, current, sensitivity = JOINTS[joint]
    rig.enable(current=current, sensitivity=sensitivity, accel_deg=accel, vel_deg=top * 6.0)
    core = rig.joint.core
    core.set_stall_detector("tracking")
    core.track.base = 10 ** 9  # record, never stop
    core.track.tau_ms = 0
    core.track = type(core.track)(10 ** 8, 0, WINDOW, CONFIRM, SAMPLE_MS)
    return rig


LOSSES = []  # (joint, phase): the motor lost position there, a real stall, not free motion




def _record(rig, seconds, out, phase=""):
    core = rig.joint.core
    before = rig.stepper.slipped_periods()  # the simulator's own count of pole slips
    t_end = rig.clock.seconds() + seconds
    seen = []
    while rig.clock.seconds() < t_end:
        rig.bus.sleep(SAMPLE_MS / 1000.0)
        rig.ping()
        track = core.track
        if track.speed:
            seen.append((track.lag, abs(track.speed)))
    if rig.stepper.slipped_periods() != before:
        LOSSES.append((rig.joint.cfg.joint, phase))
        rig.command("SETUP", *JOINTS[rig.joint.cfg.joint][2:3] * 2, 0, 0)  # re-synchronise
        rig.command("ENABLESTALLGUARD", JOINTS[rig.joint.cfg.joint][3])
    else:
        # The detector needs CONFIRM samples in a row: a run of samples can only trip it by its
        # smallest lag (at its smallest speed allowance); ringing of the transmission cannot.
        for i in range(len(seen) - CONFIRM + 1):
            run = seen[i:i + CONFIRM]
            out.append((min(lag for lag, _ in run), min(speed for _, speed in run)))


def free_motion(joint, noise, seed):
    """(lag, |field usteps per sample|) of every sample of the unobstructed motion set."""
    top, accel, _, _ = JOINTS[joint]
    samples = []
    rig = _rig(joint, noise, seed)
    for rpm in (10.0, 30.0, 100.0, 300.0, top):
        rpm = min(rpm, top)
        ramp = 2.0 * rpm * 6.0 / accel + 0.3
        rig.command("SETRPM", rpm)
        _record(rig, ramp, samples, "to %g rpm" % rpm)
        rig.command("SETRPM", -rpm)  # a reversal at the configured acceleration
        _record(rig, ramp, samples, "reversal at %g rpm" % rpm)
        rig.command("SETRPM", 0.0)
        _record(rig, ramp / 2.0, samples, "stop from %g rpm" % rpm)
    short = top * 6.0 * 0.5
    for target in (short, -short, 0.0):
        rig.command("MOVETOANGLE", target)
        _record(rig, 1.5 + 2.0 * top * 6.0 / accel, samples, "move to %g deg" % target)
    for k in range(150):  # a streamed trajectory: a new velocity every 20 ms
        rig.command("SETRPM", 0.5 * top * math.sin(2.0 * math.pi * k / 75.0))
        _record(rig, 0.02, samples, "streamed trajectory")
    rig.command("SETRPM", 0.0)
    return samples


def fit(samples):
    """(base, tau_ms, cap) with the lowest 10 and 30 rpm thresholds covering MARGIN x every sample:
    for each tau, base is what the slow samples need beyond their speed allowance, cap what the
    largest lag needs beyond base."""
    best = None
    worst = max(MARGIN * lag for lag, _ in samples)
    for tau in range(0, 21):
        base = max(MIN_BASE, max(int(MARGIN * lag - speed * tau / SAMPLE_MS) + 1 for lag, speed in samples))
        cap = max(0, int(worst - base) + 1) if SATURATE else 1000000
        cost = sum(base + min(cap, (rpm * 51200 / 60.0 * SAMPLE_MS / 1000.0) * tau / SAMPLE_MS)
                   for rpm in (10.0, 30.0))
        if best is None or cost < best[0]:
            best = (cost, base, tau, cap)
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
        samples = []
        for noise in ("nominal", "harsh", "as5600"):
            for seed in (1, 2):
                samples += free_motion(joint, noise, seed)
        base, tau, cap = fit(samples)
        decel = stop_deceleration(joint)
        worst = max(lag for lag, _ in samples)
        results[joint] = {"track_base": base, "track_tau_ms": tau, "track_cap": cap,
                          "stop_deceleration": float(decel)}
        print("%s: %d samples, largest free lag %d usteps -> track_base %d, track_tau_ms %d, track_cap %d; "
              "stop_deceleration %d full steps/s^2" % (joint, len(samples), worst, base, tau, cap, decel))
    for joint, phase in LOSSES:
        print("%s lost position (a real stall, excluded): %s" % (joint, phase))
    if "--write" in argv:
        for joint, values in results.items():
            path = os.path.join(HERE, "..", "firmware", "joint", "configs", joint + ".json")
            with open(path) as f:
                cfg = json.load(f)
            cfg["stop_deceleration"] = values["stop_deceleration"]
            cfg["stall"]["track_base"] = values["track_base"]
            cfg["stall"]["track_tau_ms"] = values["track_tau_ms"]
            cfg["stall"]["track_cap"] = values["track_cap"]
            cfg["stall"]["track_confirm"] = CONFIRM
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
