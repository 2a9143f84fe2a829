"""The encoder error each joint's firmware sees over a motor turn, before and after `bioscara
calibrate`, on the shipped arm simulated in virtual time (each joint's sensor has an error of its
own, drawn from its seed within the datasheet's bound).

The error is the simulator's truth (SimStepper.encoder_error: the firmware's encoder reading, noise
left out, against the rotor's true angle, about its mean), largest over a turn, in motor degrees;
the calibration is the command a user runs (home, then calibrate) through the host's link.

    python bench/encoder_errors.py     # safety.encoder_error_deg_max.<joint>.raw / .calibrated
"""

from __future__ import annotations

import contextlib
import io
import json
import sys
from dataclasses import replace

from bioscara import cli
from bioscara.bus.sim import SimBus
from bioscara.config import read_config
from bioscara.hardware import open_arm_bus

JOINTS = ("j1", "j2", "j3", "j4")
_POINTS = 720


def error_deg_max(bus: SimBus, address: int) -> float:
    stepper = bus.joint(address).stepper
    errors = [stepper.encoder_error(i * 360.0 / _POINTS) for i in range(_POINTS)]
    mean = sum(errors) / len(errors)
    return max(abs(e - mean) for e in errors)


def _command(bus: SimBus, *argv: str) -> dict:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        code = cli.main([*argv, "--json"], bus=bus)
    if code != 0:
        raise SystemExit(f"`bioscara {' '.join(argv)}` failed ({code})")
    return json.loads(out.getvalue().splitlines()[-1])


def figures() -> list[tuple[str, float]]:
    config = read_config()
    config = replace(config, bus=replace(config.bus, url="sim:virtual"))
    bus = open_arm_bus(config)
    assert isinstance(bus, SimBus)
    rows = []
    try:
        for name in JOINTS:
            address = config.joints[name].address
            _command(bus, "home", name)
            raw = error_deg_max(bus, address)
            measured = _command(bus, "calibrate", name)
            rows += [(f"safety.encoder_error_deg_max.{name}.raw", raw),
                     (f"safety.encoder_error_deg_max.{name}.calibrated", error_deg_max(bus, address)),
                     (f"safety.encoder_error_deg_max.{name}.measured_before", measured["error_before_deg"]),
                     (f"safety.encoder_error_deg_max.{name}.measured_after", measured["error_after_deg"])]
    finally:
        bus.close()
    return rows


if __name__ == "__main__":
    for figure, value in figures():
        print(figure, f"{value:.4f}")
    sys.exit(0)
