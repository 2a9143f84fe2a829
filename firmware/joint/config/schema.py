"""Per-joint configuration: one small JSON file next to the firmware lets one image serve J1..J4.

`load()` never raises: every problem becomes a readable line in `JointConfig.errors` (file, key,
value, allowed range) and the firmware then starts disabled instead of crashing. Keys left out
take the original firmware's constants; unknown keys are errors (they are usually typos).
Used at boot only on the board (the objects it builds are settings.py's).
"""

import json

from ..core.supervise import DETECTOR_NAMES
from ..micro import board_module
from .settings import CONFIG_FILE, JOINTS, JointConfig, Section

ADDRESSES = {"J1": 0x11, "J2": 0x12, "J3": 0x13, "J4": 0x14}
BACKENDS = ("pico", "s32", "sim")
S32_JOINT_BUS = 1  # the uStepper S32's joint bus is I2C1 (PB8 SCL, PB9 SDA), pins fixed
SAFE_ACTIONS = ("hold", "freewheel")

_INT = 0
_NUM = 1
_BOOL = 2
_STR = 3

# section -> ((key, kind, default, lo, hi), ...); for _STR `lo` is the tuple of allowed values.
SCHEMA = (
    ("", (
        ("joint", _STR, None, JOINTS, None),
        ("address", _INT, None, 0x08, 0x77),
        ("deadman_ms", _INT, 50, 10, 1000),  # the original's velocity-only deadman (boot)
        # After a deadman stop: "hold" (stay energized at the hold current, as the original did)
        # or "freewheel" (currents 0, coils open).
        ("safe_action", _STR, "hold", SAFE_ACTIONS, None),
        # Deadman stops decelerate at this rate (full steps/s^2): the fastest the motor can brake
        # the joint's inertia without losing position (bench/derive_safety.py, make derive-safety).
        ("stop_deceleration", _NUM, 11636.0, 1.0, 11636.0),
    )),
    ("i2c", (
        ("bus", _INT, 0, 0, 1),
        ("scl", _INT, 5, 0, 47),
        ("sda", _INT, 4, 0, 47),
        ("whole_reply_writes", _BOOL, True, None, None),
    )),
    ("boot", (
        ("max_acceleration", _NUM, 100.0, 1.0, 11636.0),  # full steps/s^2
        ("max_velocity", _NUM, 10.0, 0.1, 19538.0),  # full steps/s
        ("control_threshold", _NUM, 15.0, 1.0, 1000.0),  # usteps
        ("orientation_check", _NUM, 1.0, 0.1, 90.0),  # motor degrees
    )),
    ("stall", (
        ("spike_limit", _NUM, 100.0, 0.0, 100000.0),  # usteps
        ("gain", _NUM, 1.0, 0.0, 100.0),
        ("sample_time", _NUM, 0.01, 0.001, 1.0),  # s
        ("time_constant", _NUM, 0.1, 0.001, 100.0),  # s
        ("sensitivity_scale", _NUM, 10.0, 0.0, 1000.0),  # usteps per ENABLESTALLGUARD unit
        ("window_low", _NUM, 12.0, 0.0, 100000.0),  # motor rad/s
        ("window_high", _NUM, 450.0, 0.0, 100000.0),
        ("window_offset", _NUM, 90.0, 0.0, 100000.0),  # usteps
        ("slope", _NUM, 0.0, -100000.0, 100000.0),  # usteps per rad/s
        # "original": the filtered-PID-error detector above; "tracking": tracking.py, the encoder
        # no longer following the driver's field. Constants from bench/derive_safety.py.
        ("detector", _STR, "original", DETECTOR_NAMES, None),
        ("track_base", _INT, 320, 16, 100000),  # usteps of lag beyond any free-running lag
        ("track_tau_ms", _INT, 10, 0, 1000),  # plus this many ms of field travel at the speed,
        ("track_cap", _INT, 100000, 0, 1000000),  # at most this many usteps
        ("track_slope_q8", _INT, 0, 0, 255),  # encoder error per ustep of travel, /256, left out
        ("track_window", _INT, 20, 1, 64),  # samples the lag is measured over
        ("track_confirm", _INT, 2, 1, 64),  # samples in a row above the threshold
        ("track_sample_ms", _INT, 5, 1, 100),
        # load_angle.py, sampled with the tracking detector: a slow contact's load angle over the
        # same rotor angle one motor turn earlier, usteps (0: off), for this many samples in a row,
        # each sample adding at most load_clip usteps (an encoder spike).
        ("load_limit", _INT, 0, 0, 100000),
        ("load_confirm", _INT, 3, 1, 64),
        ("load_clip", _INT, 64, 1, 100000),
    )),
    ("homing", (
        # HOME ends only when the encoder lags the field by this much for `confirm` samples
        # (sampled every stall.track_sample_ms) and |PID error| exceeded the sensitivity meanwhile.
        ("evidence_usteps", _INT, 512, 64, 100000),
        ("confirm", _INT, 3, 1, 64),
        # A homing that travels farther (motor degrees, from the joint's range) or runs longer than
        # this travel at the homing speed (x 1.5, + 3 s) ends NOTHOMED.
        ("max_travel_deg", _NUM, 36000.0, 1.0, 1e6),
        # The PID-error noise floor while moving: control threshold + this x speed (rpm); a
        # sensitivity at or below it is refused. 0.5534 = usteps per ISR tick per rpm (1541.85 Hz).
        ("floor_per_rpm", _NUM, 0.5534, 0.0, 100.0),
    )),
)


def _kind_ok(kind, value):
    if type(value) is bool:
        return kind == _BOOL
    if kind == _INT:
        return type(value) is int
    if kind == _NUM:
        return type(value) in (int, float)
    if kind == _STR:
        return type(value) is str
    return False


def _check(cfg, path, spec, value):
    key, kind, default, lo, hi = spec
    kinds = ("an integer", "a number", "true or false", "a string")
    if not _kind_ok(kind, value):
        cfg.errors.append("%s: %s must be %s, got %r" % (cfg.source, path, kinds[kind], value))
        return default
    if kind == _STR:
        if value not in lo:
            cfg.errors.append("%s: %s = %r is not one of %s" % (cfg.source, path, value, ", ".join(lo)))
            return default
    elif kind in (_INT, _NUM) and not (lo <= value <= hi):
        cfg.errors.append("%s: %s = %r is out of range %s..%s" % (cfg.source, path, value, lo, hi))
        return default
    return float(value) if kind == _NUM else value


def parse(data, source=CONFIG_FILE):
    """Validate a decoded config dict; always returns a JointConfig (check `.errors`)."""
    cfg = JointConfig(source)
    if type(data) is not dict:
        cfg.errors.append("%s: the top level must be a JSON object" % source)
        data = {}
    top_keys = ["motor", "encoder"]
    for section, specs in SCHEMA:
        raw = data
        if section:
            top_keys.append(section)
            raw = data.get(section, {})
            if type(raw) is not dict:
                cfg.errors.append("%s: %s must be an object" % (source, section))
                raw = {}
            keys = [spec[0] for spec in specs]
            for key in raw:
                if key not in keys:
                    cfg.errors.append("%s: unknown key %s.%s" % (source, section, key))
        values = {}
        for spec in specs:
            key = spec[0]
            path = section + "." + key if section else key
            if not section:
                top_keys.append(key)
            if key in raw:
                values[key] = _check(cfg, path, spec, raw[key])
            elif spec[2] is None:
                cfg.errors.append("%s: missing required key %s" % (source, path))
                values[key] = None
            else:
                values[key] = spec[2]
        if section:
            setattr(cfg, section, Section(values))
        else:
            for key in values:
                setattr(cfg, key, values[key])
    for key in data:
        if key not in top_keys:
            cfg.errors.append("%s: unknown key %s" % (source, key))
    stall = cfg.stall
    if stall.window_low > stall.window_high:
        cfg.errors.append("%s: stall.window_low (%s) must not exceed stall.window_high (%s)"
                          % (source, stall.window_low, stall.window_high))
    if stall.track_confirm > stall.track_window:
        cfg.errors.append("%s: stall.track_confirm must not exceed stall.track_window" % source)
    if stall.sample_time >= stall.time_constant:
        cfg.errors.append("%s: stall.sample_time must be below stall.time_constant" % source)
    _parse_motor(cfg, data.get("motor", {"backend": "sim"}))
    _parse_encoder(cfg, data.get("encoder", {}))
    return cfg


def _parse_encoder(cfg, encoder):
    """encoder.correction (`bioscara calibrate`): the encoder's error over its turn, motor
    millidegrees at 16, 32 or 64 equally spaced angles from the sensor's zero, each within 5
    degrees, twice the TLE5012B's worst case over temperature (a larger error is a misplaced
    magnet, which no table should hide). A bad table is an error and is not used. The messages
    reuse _check's and parse's formats: every new string or name is a qstr the board keeps for
    good (with messages of its own, this check made the board's qstr pool grow by 7.9 KB)."""
    known = len(cfg.errors)
    if type(encoder) is not dict:
        cfg.errors.append("%s: %s must be an object" % (cfg.source, "encoder"))
        encoder = {}
    for key in encoder:
        if key != "correction":
            cfg.errors.append("%s: unknown key %s.%s" % (cfg.source, "encoder", key))
    raw = encoder.get("correction", [])
    if type(raw) is not list or len(raw) not in (0, 16, 32, 64):
        cfg.errors.append("%s: %s must be %s, got %r" % (cfg.source, "encoder.correction", "a list of 16, 32 or 64 "
                          "integers (motor millidegrees)", len(raw) if type(raw) is list else raw))
    else:
        for value in raw:  # a loop, not a comprehension: no function object to outlive the boot
            _check(cfg, "encoder.correction", ("correction", _INT, 0, -5000, 5000), value)
            if len(cfg.errors) > known:
                break
    cfg.encoder = Section({"correction": tuple(raw) if len(cfg.errors) == known else ()})


def _parse_motor(cfg, motor):
    if type(motor) is not dict:
        cfg.errors.append("%s: motor must be an object" % cfg.source)
        return
    backend = motor.get("backend")
    if backend not in BACKENDS:
        cfg.errors.append("%s: motor.backend = %r is not one of %s" % (cfg.source, backend, ", ".join(BACKENDS)))
        return
    if backend == "pico":
        motor_config = board_module(__name__[:-len(".config.schema")], "pico.motor_config")
        is_i2c_pin = motor_config.is_i2c_pin
        bus = cfg.i2c
        for key, scl, role in (("sda", False, "SDA"), ("scl", True, "SCL")):
            pin = getattr(bus, key)
            if not is_i2c_pin(pin, bus.bus, scl):
                cfg.errors.append("%s: i2c.%s = %d is not an %s pin of I2C%d on the Pico"
                                  % (cfg.source, key, pin, role, bus.bus))
        for problem in motor_config.validate_motor_config(motor, {"bus": bus.bus, "sda": bus.sda, "scl": bus.scl}):
            cfg.errors.append("%s: motor: %s" % (cfg.source, problem))
    elif backend == "s32":
        if cfg.i2c.bus != S32_JOINT_BUS:
            cfg.errors.append("%s: i2c.bus = %d: the uStepper S32's joint bus is I2C%d (PB8/PB9)"
                              % (cfg.source, cfg.i2c.bus, S32_JOINT_BUS))
        for key in motor:
            if key != "backend":
                cfg.errors.append("%s: unknown key motor.%s (the s32 backend has no settings)" % (cfg.source, key))
    cfg.motor = motor


def load(path=CONFIG_FILE):
    """Read and validate the config file at `path`; never raises (a bad file is a disabled joint)."""
    try:
        with open(path, "rb") as f:
            raw = f.read()
    except OSError as exc:
        return _unusable(path, "cannot read the file (%s)" % (exc,))
    return parse_bytes(raw, path)


def parse_bytes(raw, source):
    """Decode and validate a configuration's bytes (a file's, or flash's on a board without a
    filesystem); never raises."""
    try:
        text = raw.decode("utf-8")
    except UnicodeError:  # MicroPython raises UnicodeError, CPython its subclass
        return _unusable(source, "not UTF-8 text")
    try:
        data = json.loads(text)
    except ValueError as exc:
        return _unusable(source, "not valid JSON (%s)" % (exc,))
    except (RuntimeError, MemoryError):  # nesting deeper than the parser's recursion (or RAM) allows
        return _unusable(source, "not valid JSON (nested too deeply)")
    return parse(data, source)


def _unusable(path, why):
    cfg = parse({}, path)
    cfg.errors.insert(0, "%s: %s" % (path, why))
    return cfg


def default(joint="J1", backend="sim"):
    """A valid config for `joint` with the original firmware's constants."""
    return parse({"joint": joint, "address": ADDRESSES[joint], "motor": {"backend": backend}},
                 "defaults for " + joint)
