"""Arm configuration: the TOML file that replaces the original's URDF/YAML hardware parameters.

`load_config()` gives the configuration a program runs with, the same for the command line and
the Python API: `--config`'s file, else the user's, else the shipped one, on the bus `--bus` or
$BIOSCARA_BUS names, else the file's. `read_config()` reads one file (or the shipped default) as it
is, `parse_config()` checks an already parsed table. Both collect every problem before raising one `ConfigError` that lists them all, each line
naming the file, the key path and what is allowed. Joint values are in joint units: rad for revolute
joints, m for prismatic ones.
"""

from __future__ import annotations

import difflib
import math
import os
import tomllib
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Any, Literal

from .errors import ConfigError
from .firmware.spec import protocol as P
from .transmission import Transmission
from .transports import schemes

JointType = Literal["revolute", "prismatic"]

JOINT_NAMES = ("j1", "j2", "j3", "j4")

# Default simulated start: this far inside the end stop that homing runs into.
_SIM_START_MARGIN = {"revolute": 0.05, "prismatic": 0.005}  # rad, m


@dataclass(frozen=True)
class BusConfig:
    """How the host reaches the joints."""

    url: str = "sim:"  # smbus:N | blinka: | serial:/dev/tty... | sim:
    speed_hz: int = 400_000  # I2C clock, Hz
    attempts: int = 3  # transfer attempts before COMM_ERROR
    use_mock_hardware: bool = False  # True: ignore url and simulate the joints in this process


@dataclass(frozen=True)
class HomingConfig:
    """Parameters of the HOME command, in joint units."""

    speed: float  # joint units/s, > 0; the sign of the home command picks the direction
    threshold: int  # |PID error| end-stop threshold, 0..255
    current: int  # motor current during homing, % 0..100
    acceleration: float  # joint units/s^2, > 0
    direction: int = -1  # default direction (-1 or +1) for `home all` and the demo
    # Check after homing that the stop found is plausible: the homing travelled no more than the
    # joint's range, and (re-homing) about as far as the end stop was from where it started.
    check_range: bool = False
    range_tolerance: float = 0.0  # joint units allowed on top of the check's own slack
    hold: bool = False  # stay energized (hold current) between home mode starting and homing


@dataclass(frozen=True)
class JointConfig:
    """One joint. Transmission: motor angle [rad] = reduction * (joint - offset); homing finds the offset."""

    name: str  # "j1".."j4"
    type: JointType  # revolute (rad) or prismatic (m)
    address: int  # I2C address, 0x08..0x77
    reduction: float  # motor rad per joint unit; the sign is the motor's mounting direction
    min: float  # joint units
    max: float  # joint units
    stall_threshold: int  # 0..255, 0 disables stall detection
    hold_current: int  # % 0..100
    drive_current: int  # % 0..100
    max_acceleration: float  # joint units/s^2
    max_velocity: float  # joint units/s
    homing: HomingConfig
    watchdog_ms: int = 100  # host-silence timeout for every motion mode, 0: the firmware's original


@dataclass(frozen=True)
class GripperConfig:
    """Servo parallel gripper. Width w (m) maps to servo angle reduction * (w - offset) degrees."""

    reduction: float  # servo degrees per metre of width
    offset: float  # m, width at servo angle 0
    min: float  # m
    max: float  # m
    init_pos: float  # m, used when no valid saved position exists
    pwm_chip: int = 0
    pwm_channel: int = 0
    frequency_hz: float = 50.0
    servo_min_us: float = 500.0  # pulses are clamped to [servo_min_us, servo_max_us]
    servo_max_us: float = 2500.0
    servo_speed: float = 0.2  # m/s of width, for the position estimate
    state_file: str = ""  # empty: the XDG state directory (see bioscara.gripper)
    use_mock: bool = False


@dataclass(frozen=True)
class SimConfig:
    """The simulated arm behind the `sim:` bus."""

    seed: int = 1
    realtime: bool = False
    payload_kg: float = 0.0  # carried by the gripper: the simulated arm's inertia (and J2's weight)
    noise: str = "nominal"  # encoder and ISR corner of the simulated arm: "nominal" or "harsh"
    idle_exit_min: float = 15.0  # the shared arm (sim:) ends after this long unused; 0: never
    start: dict[str, float] = field(default_factory=dict)  # joint units, one entry per configured joint


@dataclass(frozen=True)
class ArmConfig:
    """The whole arm. `joints` is ordered j1..j4; `source` names the file it came from."""

    bus: BusConfig
    joints: dict[str, JointConfig]
    gripper: GripperConfig | None
    sim: SimConfig
    source: str

    @property
    def bus_url(self) -> str:
        """The bus to open: joints simulated in this process (virtual time) when use_mock_hardware is set."""
        return "sim:virtual" if self.bus.use_mock_hardware else self.bus.url


USER_CONFIG_NAME = "arm.toml"
BUS_ENV = "BIOSCARA_BUS"
IDLE_EXIT_ENV = "BIOSCARA_SIM_IDLE_EXIT"  # minutes: overrides sim.idle_exit_min (test runs shorten it)


def user_config_path() -> Path:
    """$XDG_CONFIG_HOME/bioscara/arm.toml: the configuration commands use when given no --config."""
    from .paths import default_config_dir
    return default_config_dir() / USER_CONFIG_NAME


def load_config(path: str | os.PathLike[str] | None = None, bus: str | None = None) -> ArmConfig:
    """The configuration a program runs with (the command line's `--config` and `--bus` are
    `path` and `bus`; a script passes nothing to get what `bioscara` commands use).

    The file: `path`, else the user's (`user_config_path()`) if it exists, else the shipped one.
    The bus: `bus` (--bus), else $BIOSCARA_BUS, else the file's. The shared simulated arm's idle
    exit: $BIOSCARA_SIM_IDLE_EXIT (minutes), else the file's `sim.idle_exit_min`.
    """
    if path is None and user_config_path().is_file():
        path = user_config_path()
    config = read_config(path)
    url = bus or os.environ.get(BUS_ENV, "").strip() or None
    if url is not None:
        if not bus and not url.startswith(schemes()):
            raise ConfigError(f"unknown bus {url!r} in ${BUS_ENV}; use one of {', '.join(schemes())}")
        config = replace(config, bus=replace(config.bus, url=url, use_mock_hardware=False))
    idle = os.environ.get(IDLE_EXIT_ENV, "").strip()
    if idle:
        try:
            minutes = float(idle)
        except ValueError:
            minutes = -1.0
        if not 0 <= minutes <= 7 * 24 * 60:
            raise ConfigError(f"${IDLE_EXIT_ENV} = {idle[:24]!r} must be minutes in 0..10080 (0: never)")
        config = replace(config, sim=replace(config.sim, idle_exit_min=minutes))
    return config


def read_config(path: str | os.PathLike[str] | None = None) -> ArmConfig:
    """Read and check one configuration file as it is (no user file, no environment); None reads
    the shipped default."""
    if path is None:
        resource = resources.files("bioscara").joinpath("data/default.toml")
        source, read = str(resource), resource.read_bytes
    else:
        source = os.fspath(path)
        read = Path(source).read_bytes
    try:
        raw = read()
    except OSError as e:
        raise ConfigError(f"{source}: cannot read the file ({e.strerror or e})") from e
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError as e:
        raise ConfigError(f"{source}: not valid TOML (not UTF-8 text: {e.reason} at byte {e.start})") from e
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{source}: not valid TOML ({e})") from e
    except ValueError as e:  # an integer literal longer than Python converts (4300 digits)
        raise ConfigError(f"{source}: not valid TOML ({str(e)[:80]})") from e
    except RecursionError:
        raise ConfigError(f"{source}: not valid TOML (arrays or tables nested too deeply)") from None
    return parse_config(data, source)


def parse_config(data: dict[str, Any], source: str) -> ArmConfig:
    """Check a parsed configuration table and build the ArmConfig; raises ConfigError listing every problem.

    `source` names the file in the messages.
    """
    p = _Problems(source)
    _section(p, data, "", {"bus", "joints", "gripper", "sim"})
    bus = _bus(p, data)
    joints = _joints(p, data)
    gripper = _gripper(p, data) if "gripper" in data else None
    sim = _sim(p, data, joints)
    if p.lines:
        raise ConfigError("\n".join(p.lines))
    return ArmConfig(bus=bus, joints=joints, gripper=gripper, sim=sim, source=source)


class _Problems:
    def __init__(self, source: str) -> None:
        self.source = source
        self.lines: list[str] = []

    def add(self, message: str) -> None:
        self.lines.append(f"{self.source}: {message}")


_REQUIRED = object()


@dataclass(frozen=True)
class _Key:
    """What one key accepts. Bounds are inclusive except `above`, which is exclusive."""

    kind: type  # int, float, str or bool
    lo: float | None = None
    hi: float | None = None
    above: float | None = None
    nonzero: bool = False
    choices: tuple[object, ...] = ()
    default: object = _REQUIRED
    as_hex: bool = False

    def allowed(self) -> str:
        if self.choices:
            return "one of " + ", ".join(_show(c, self.as_hex) for c in self.choices)
        if self.nonzero:
            return "a non-zero number"
        what = {int: "an integer", float: "a number", str: "a string", bool: "true or false"}[self.kind]
        if self.lo is not None and self.hi is not None:
            return f"{what} {self.range()}"
        if self.above is not None:
            return f"{what} > {self.above:g}"
        return what

    def range(self) -> str:
        return f"{_show(self.lo, self.as_hex)}..{_show(self.hi, self.as_hex)}"


def _int(lo: int, hi: int, default: object = _REQUIRED, as_hex: bool = False) -> _Key:
    return _Key(int, lo=lo, hi=hi, default=default, as_hex=as_hex)


def _positive(default: object = _REQUIRED) -> _Key:
    return _Key(float, above=0.0, default=default)


_NUMBER = _Key(float)

_BUS_KEYS = {
    "url": _Key(str, default="sim:"),
    "speed_hz": _int(10_000, 3_400_000, default=400_000),
    "attempts": _int(1, 10, default=3),
    "use_mock_hardware": _Key(bool, default=False),
}
_JOINT_KEYS = {
    "type": _Key(str, choices=("revolute", "prismatic")),
    "address": _int(0x08, 0x77, as_hex=True),
    "reduction": _Key(float, nonzero=True),
    "min": _NUMBER,
    "max": _NUMBER,
    "stall_threshold": _int(0, 255),
    "hold_current": _int(0, 100),
    "drive_current": _int(0, 100),
    "max_acceleration": _positive(),
    "max_velocity": _positive(),
    "watchdog_ms": _int(0, 5000, default=100),
}
_HOMING_KEYS = {
    "speed": _positive(),
    "threshold": _int(0, 255),
    "current": _int(0, 100),
    "acceleration": _positive(),
    "direction": _Key(int, choices=(-1, 1), default=-1),
    "check_range": _Key(bool, default=False),
    "range_tolerance": _Key(float, lo=0.0, hi=1e6, default=0.0),
    "hold": _Key(bool, default=False),
}
_GRIPPER_KEYS = {
    "reduction": _Key(float, nonzero=True),
    "offset": _NUMBER,
    "min": _NUMBER,
    "max": _NUMBER,
    "init_pos": _NUMBER,
    "pwm_chip": _int(0, 1023, default=0),
    "pwm_channel": _int(0, 1023, default=0),
    "frequency_hz": _positive(default=50.0),
    "servo_min_us": _positive(default=500.0),
    "servo_max_us": _positive(default=2500.0),
    "servo_speed": _positive(default=0.2),
    "state_file": _Key(str, default=""),
    "use_mock": _Key(bool, default=False),
}
_SIM_KEYS = {
    "seed": _Key(int, default=1),
    "realtime": _Key(bool, default=False),
    "payload_kg": _Key(float, lo=0.0, hi=5.0, default=0.0),
    "noise": _Key(str, choices=("nominal", "harsh"), default="nominal"),
    "idle_exit_min": _Key(float, lo=0.0, hi=7 * 24 * 60.0, default=15.0),
}


def _bus(p: _Problems, top: dict[str, Any]) -> BusConfig:
    table = _section(p, _table(p, top, "bus"), "bus", set(_BUS_KEYS))
    values = _read(p, table, "bus", _BUS_KEYS)
    if "url" in values and not values["url"].startswith(schemes()):
        p.add(f"bus.url = {_show(values['url'])} must start with one of {', '.join(schemes())}")
    return BusConfig(**values)


def _joints(p: _Problems, top: dict[str, Any]) -> dict[str, JointConfig]:
    table = _section(p, _table(p, top, "joints"), "joints", set(JOINT_NAMES), what="joint")
    if not any(name in table for name in JOINT_NAMES) and isinstance(top.get("joints", {}), dict):
        p.add("joints is missing: at least one of the tables joints.j1..joints.j4 is required")
    joints: dict[str, JointConfig] = {}
    used: dict[int, str] = {}
    for name in JOINT_NAMES:  # the order of the arm, whatever the order in the file
        if name not in table:
            continue
        path = f"joints.{name}"
        jt = _section(p, _table(p, table, name, path), path, set(_JOINT_KEYS) | {"homing"})
        values = _read(p, jt, path, _JOINT_KEYS)
        ordered = _check_order(p, values, path)
        if "homing" in jt:
            ht = _section(p, _table(p, jt, "homing", f"{path}.homing"), f"{path}.homing", set(_HOMING_KEYS))
            homing = _read(p, ht, f"{path}.homing", _HOMING_KEYS)
        else:
            p.add(f"{path}.homing is missing (a table with speed, threshold, current, acceleration)")
            homing = {}
        address = values.get("address")
        if address in used:
            p.add(f"{path}.address {_show(address, as_hex=True)} is already used by {used[address]}")
        elif address is not None:
            used[address] = name
        if ordered and len(values) == len(_JOINT_KEYS) and len(homing) == len(_HOMING_KEYS):
            joint = JointConfig(name=name, homing=HomingConfig(**homing), **values)
            if _check_motor_side(p, joint, path):
                joints[name] = joint
    return joints


def _check_motor_side(p: _Problems, jc: JointConfig, path: str) -> bool:
    """What the joint values become at the motor must be what the protocol accepts (protocol.py)."""
    t = Transmission(jc.reduction)
    ok = True
    rpm = abs(t.motor_rpm(jc.homing.speed))
    if not 1.0 <= rpm <= 250.0:
        p.add(f"{path}.homing.speed = {jc.homing.speed} is {rpm:.3g} motor RPM with reduction "
              f"{jc.reduction}; homing needs 1..250 RPM")
        ok = False
    for key, value in (("max_velocity", jc.max_velocity), ("max_acceleration", jc.max_acceleration),
                       ("homing.acceleration", jc.homing.acceleration)):
        motor = t.motor_limit(value)
        if not 1e-3 <= motor <= 1e6:
            p.add(f"{path}.{key} = {value} is {motor:.3g} motor degrees (/s, /s^2) with reduction "
                  f"{jc.reduction}; the joint accepts 0.001..1e6")
            ok = False
    span = abs(t.motor_degrees(jc.max) - t.motor_degrees(jc.min))
    move_limit = P.register("MOVETOANGLE").write[0].hi
    if span > move_limit:
        p.add(f"{path}: min..max spans {span:.3g} motor degrees; the joint accepts at most {move_limit:g}")
        ok = False
    return ok


def _gripper(p: _Problems, top: dict[str, Any]) -> GripperConfig | None:
    table = _section(p, _table(p, top, "gripper"), "gripper", set(_GRIPPER_KEYS))
    values = _read(p, table, "gripper", _GRIPPER_KEYS)
    ordered = _check_order(p, values, "gripper")
    lo, hi, init = values.get("min"), values.get("max"), values.get("init_pos")
    if ordered and init is not None and not lo <= init <= hi:
        p.add(f"gripper.init_pos ({init!r}) must lie within min..max ({lo!r}..{hi!r})")
    low_us, high_us, hz = values.get("servo_min_us"), values.get("servo_max_us"), values.get("frequency_hz")
    if low_us is not None and high_us is not None and low_us >= high_us:
        p.add(f"gripper.servo_min_us ({low_us!r}) must be below servo_max_us ({high_us!r})")
    if high_us is not None and hz is not None and high_us > 1e6 / hz:
        p.add(f"gripper.servo_max_us ({high_us!r}) must not exceed the PWM period ({1e6 / hz:g} us at {hz:g} Hz)")
    state_file = values.get("state_file", "")
    if state_file and not os.path.isabs(os.path.expanduser(state_file)):
        # A relative path would depend on the working directory, as the original's last_pos.b did.
        p.add(f"gripper.state_file = {_show(state_file)} must be an absolute path (or empty for the default)")
    return GripperConfig(**values) if ordered and len(values) == len(_GRIPPER_KEYS) else None


def _sim(p: _Problems, top: dict[str, Any], joints: dict[str, JointConfig]) -> SimConfig:
    table = _section(p, _table(p, top, "sim"), "sim", set(_SIM_KEYS) | {"start"})
    values = _read(p, table, "sim", _SIM_KEYS)
    joints_table = top.get("joints")
    declared = joints_table if isinstance(joints_table, dict) else {}
    start_table = _section(p, _table(p, table, "start", "sim.start"), "sim.start",
                           {name for name in JOINT_NAMES if name in declared}, what="joint")
    start: dict[str, float] = {}
    for name in JOINT_NAMES:
        joint = joints.get(name)
        if name in start_table:
            value = _check(p, f"sim.start.{name}", start_table[name], _NUMBER)
            if value is None or joint is None:
                continue
            if not joint.min <= value <= joint.max:
                p.add(f"sim.start.{name} = {value!r} is outside the joint range {joint.min!r}..{joint.max!r}")
            start[name] = value
        elif joint is not None:
            margin = min(_SIM_START_MARGIN[joint.type], (joint.max - joint.min) / 2)
            end_stop = joint.min if joint.homing.direction < 0 else joint.max
            start[name] = end_stop - joint.homing.direction * margin
    return SimConfig(start=start, **values)


def _check_order(p: _Problems, values: dict[str, Any], path: str) -> bool:
    """Whether min and max are both valid and in order; reports them when they are not in order."""
    lo, hi = values.get("min"), values.get("max")
    if lo is None or hi is None:
        return False
    if lo >= hi:
        p.add(f"{path}.min ({lo!r}) must be below max ({hi!r})")
        return False
    return True


def _table(p: _Problems, parent: dict[str, Any], key: str, path: str | None = None) -> dict[str, Any]:
    """parent[key] when it is a table; an absent table reads as empty."""
    value = parent.get(key, {})
    if isinstance(value, dict):
        return value
    p.add(f"{path or key} = {_show(value)} must be a table")
    return {}


def _section(p: _Problems, table: dict[str, Any], path: str, allowed: set[str], what: str = "key") -> dict[str, Any]:
    """Report the keys of `table` that are not allowed; return the table itself."""
    for key in table:
        if key not in allowed:
            near = difflib.get_close_matches(key, sorted(allowed), n=1) if len(key) < 100 else []
            hint = f"did you mean {near[0]}?" if near else "allowed: " + (", ".join(sorted(allowed)) or "none")
            shown = key if len(key) <= 60 else key[:57] + "..."
            p.add(f"unknown {what} {path + '.' if path else ''}{shown} ({hint})")
    return table


def _read(p: _Problems, table: dict[str, Any], path: str, keys: dict[str, _Key]) -> dict[str, Any]:
    """The checked values of `keys`, defaults filled in; keys with a problem are reported and left out."""
    values: dict[str, Any] = {}
    for key, spec in keys.items():
        if key in table:
            value = _check(p, f"{path}.{key}", table[key], spec)
            if value is not None:
                values[key] = value
        elif spec.default is not _REQUIRED:
            values[key] = spec.default
        else:
            p.add(f"{path}.{key} is missing ({spec.allowed()})")
    return values


def _check(p: _Problems, path: str, value: object, spec: _Key) -> Any:
    """`value` as spec.kind, or None after reporting why it is not acceptable."""
    shown = _show(value, spec.as_hex)
    if isinstance(value, bool) and spec.kind is not bool:
        p.add(f"{path} = {shown} must be {spec.allowed()}, not a boolean")
        return None
    if spec.kind is float and type(value) is int:
        if abs(value) > 1e300:
            p.add(f"{path} = {shown} is too large a number")
            return None
        value = float(value)
    if type(value) is not spec.kind:  # also refuses 20.5 (or 20.0) where an integer is expected
        p.add(f"{path} = {shown} must be {spec.allowed()}")
        return None
    if spec.choices:
        if value not in spec.choices:
            p.add(f"{path} = {shown} must be {spec.allowed()}")
            return None
        return value
    if not isinstance(value, (int, float)):
        return value
    if isinstance(value, float) and not math.isfinite(value):
        p.add(f"{path} = {shown} must be a finite number")
    elif spec.lo is not None and spec.hi is not None and not spec.lo <= value <= spec.hi:
        p.add(f"{path} = {shown} is out of range {spec.range()}")
    elif spec.above is not None and not value > spec.above:
        p.add(f"{path} = {shown} must be > {spec.above:g}")
    elif spec.nonzero and value == 0:
        p.add(f"{path} = {shown} must be non-zero")
    else:
        return value
    return None


def _show(value: object, as_hex: bool = False) -> str:
    """A value as it would be written in TOML, shortened to a readable length."""
    text = _toml(value, as_hex)
    return text if len(text) <= 60 else text[:57] + "..."


def _toml(value: object, as_hex: bool) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return f"0x{value:02X}" if as_hex else str(value)
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, dict):
        return "a table"
    if isinstance(value, list):
        return "an array"
    return repr(value)
