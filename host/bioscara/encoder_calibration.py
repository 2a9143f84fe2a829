"""Encoder calibration (`bioscara calibrate JOINT`): the encoder's error over one motor turn,
measured on slow unloaded turns, fitted, and stored in the joint's configuration file
(`encoder.correction`), which its firmware subtracts from every encoder reading from its next boot.

The measurement: at a constant slow speed the rotor follows the coil field at a constant load
angle, so its true angle is a straight line in time; what the encoder reads beyond that line is its
error. The error of a magnetic angle sensor repeats every turn of its magnet, so it is fitted as
the first `HARMONICS` harmonics of the sensor's own angle (ENCODERZERO + ANGLEMOVED), one line per
turning direction (the load angle changes sign with the direction), and tabulated at
`TABLE_SIZE` equally spaced angles in motor millidegrees, as the firmware's schema takes it.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np

from .bus import Bus
from .errors import ConfigError, IncorrectStateError
from .firmware.config import schema as firmware_config
from .joint import Joint

HARMONICS = 4  # the TLE5012B's and AS5600's error is mostly 1x and 2x a turn; 3x, 4x cost nothing
TABLE_SIZE = 32  # linear interpolation of 4x a turn over 32 points: within 2 % of its amplitude
SPEED_RPM = 10.0  # motor rpm: slow enough for a quasi-static load angle, a turn in 6 s
TURNS = 1.25  # each way; the first quarter turn (the speed ramp) is not fitted
SETTLE_TURNS = 0.25
SAMPLE_S = 0.005
_GRID = 3600  # points over a turn at which the peak error is taken


@dataclass(frozen=True)
class Sweep:
    """Encoder readings of one slow turn: bus time (s) and ANGLEMOVED (motor degrees)."""

    direction: int
    times: np.ndarray
    degrees: np.ndarray


@dataclass(frozen=True)
class Fit:
    """The encoder's error as harmonics of the sensor's own angle, motor degrees."""

    cosines: np.ndarray  # degrees, harmonic 1..HARMONICS
    sines: np.ndarray
    residual_rms_deg: float  # what the harmonics do not explain (the sensor's noise, timing)

    def error_deg(self, sensor_deg: np.ndarray) -> np.ndarray:
        """The fitted error (degrees) at the sensor's angles `sensor_deg` (degrees in its turn)."""
        phase = np.radians(np.asarray(sensor_deg, dtype=float))
        k = np.arange(1, len(self.cosines) + 1)
        return np.cos(np.outer(phase, k)) @ self.cosines + np.sin(np.outer(phase, k)) @ self.sines

    @property
    def peak_deg(self) -> float:
        """The largest |error| over a turn, degrees."""
        return float(np.max(np.abs(self.error_deg(np.arange(_GRID) * 360.0 / _GRID))))

    def table_millideg(self, size: int = TABLE_SIZE) -> list[int]:
        """The error at `size` equally spaced angles of the sensor's turn, motor millidegrees."""
        return [int(round(1000.0 * e)) for e in self.error_deg(np.arange(size) * 360.0 / size)]


def sweep(joint: Joint, bus: Bus, direction: int, *, rpm: float = SPEED_RPM, turns: float = TURNS,
          sample_s: float = SAMPLE_S, timeout: float | None = None) -> Sweep:
    """Turn the motor `turns` turns at `rpm` (sign: `direction`) in velocity mode, reading the
    encoder every `sample_s`, then stop and wait for rest. The joint must be enabled and homed;
    IncorrectStateError when it does not get there within `timeout` (default: twice the time)."""
    duration = turns * 60.0 / rpm
    deadline = bus.monotonic() + (timeout if timeout is not None else 2.0 * duration + 2.0)
    command = joint.velocity_command(joint.transmission.velocity(direction * rpm))
    times: list[float] = []
    degrees: list[float] = []
    start = None
    while True:
        if joint.cycle(command) is not None:
            if start is None:
                start = joint.position_deg
            times.append(joint.state_time)
            degrees.append(joint.position_deg)
            if abs(joint.position_deg - start) >= turns * 360.0:
                break
        if bus.monotonic() > deadline:
            joint.stop()
            turned = abs(degrees[-1] - degrees[0]) if degrees else 0.0
            raise IncorrectStateError(f"turned {turned:.0f} of {turns * 360:.0f} motor degrees in twice the "
                                      f"{duration:.0f} s it takes: is the motor free to turn?", joint=joint.name)
        bus.sleep(sample_s)
    halt(joint, bus, deadline + 5.0)
    return Sweep(direction, np.array(times), np.array(degrees))


def halt(joint: Joint, bus: Bus, deadline: float) -> None:
    """Velocity 0, then wait (bus clock, until `deadline`) until the encoder says the motor rests."""
    command = joint.velocity_command(0.0)
    while True:
        state = joint.cycle(command)
        if state is not None and abs(joint.velocity_rpm) < 0.05:
            return
        if bus.monotonic() > deadline:
            raise IncorrectStateError("the motor did not come to rest", joint=joint.name)
        bus.sleep(SAMPLE_S)


def fit(sweeps: list[Sweep], zero_deg: float, harmonics: int = HARMONICS) -> Fit:
    """Least squares over the sweeps: per sweep an offset and a speed (the rotor's straight line),
    shared harmonics of the sensor's angle (`zero_deg` + ANGLEMOVED) for the encoder's error.
    The first SETTLE_TURNS of each sweep (the speed ramp) are left out."""
    rows, values = [], []
    for i, s in enumerate(sweeps):
        keep = np.abs(s.degrees - s.degrees[0]) >= SETTLE_TURNS * 360.0
        t = s.times[keep] - s.times[0]
        if len(t) < 8 * harmonics:
            raise IncorrectStateError(f"only {len(t)} encoder readings in a turn: the link is too slow")
        phase = np.radians(s.degrees[keep] + zero_deg)
        k = np.arange(1, harmonics + 1)
        line = np.zeros((len(t), 2 * len(sweeps)))
        line[:, 2 * i] = 1.0
        line[:, 2 * i + 1] = t
        rows.append(np.hstack([line, np.cos(np.outer(phase, k)), np.sin(np.outer(phase, k))]))
        values.append(s.degrees[keep])
    design, measured = np.vstack(rows), np.concatenate(values)
    solution, *_ = np.linalg.lstsq(design, measured, rcond=None)
    residual = measured - design @ solution
    n = 2 * len(sweeps)
    return Fit(solution[n:n + harmonics], solution[n + harmonics:], float(np.sqrt(np.mean(residual ** 2))))


def with_correction(config_file: bytes, table_millideg: list[int], source: str) -> bytes:
    """The joint's configuration file with `encoder.correction` set to the table, checked as its
    firmware will check it (ConfigError, naming the problem, when it would refuse it)."""
    data = decode(config_file, source)
    data["encoder"] = {"correction": table_millideg}
    cfg = firmware_config.parse(data, source)
    if not cfg.valid:
        raise ConfigError("; ".join(cfg.errors))
    return json.dumps(data, indent=2).encode() + b"\n"


def correction_in(config_file: bytes, source: str) -> list[int]:
    """The correction table a configuration file holds (empty: none)."""
    cfg = firmware_config.parse(decode(config_file, source), source)
    return list(cfg.encoder.correction) if cfg.valid else []


def decode(config_file: bytes, source: str) -> dict:
    try:
        data = json.loads(config_file)
    except ValueError as exc:
        raise ConfigError(f"{source}: not valid JSON ({exc})") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: the top level must be a JSON object")
    return data


def combined(old_millideg: list[int], residual_millideg: list[int]) -> list[int]:
    """A table already in use plus the error measured through it (both over the sensor's turn; a
    table of another size is interpolated onto the new one's angles)."""
    size = len(residual_millideg)
    if not old_millideg:
        return list(residual_millideg)
    old = np.asarray(old_millideg, dtype=float)
    at = np.arange(size) * len(old) / size
    low = np.floor(at).astype(int)
    frac = at - low
    interpolated = old[low % len(old)] * (1.0 - frac) + old[(low + 1) % len(old)] * frac
    return [int(round(v)) for v in interpolated + np.asarray(residual_millideg, dtype=float)]


def room_needed(joint: Joint, turns: float = TURNS) -> float:
    """Joint travel (joint units) of `turns` motor turns."""
    return abs(math.radians(360.0 * turns) / joint.transmission.reduction)
