"""The Pico backend's motor configuration: defaults, pins and their validation (boot only).

A module of its own because nothing here runs after boot: `app.build` drops it from
`sys.modules` once the joint is built, and its code and tables leave the heap.
"""

from . import tmc2209 as tmc
from .stepgen import MIN_PERIOD, SM_FREQ

DEFAULT_PINS = {
    "uart": 1, "uart_tx": 8, "uart_rx": 9,
    "encoder_i2c": 1, "encoder_sda": 6, "encoder_scl": 7,
    "step": 10, "dir": 11, "enable": 12,
}

DEFAULTS = dict(DEFAULT_PINS)
DEFAULTS.update({
    "uart_baud": 115200,
    "tmc_address": 0,
    "encoder_freq": 1000000,  # the AS5600 does Fast-mode Plus: its read blocks the loop 2.5x less
    "encoder_slow_filter": 3,  # 2x: 0.286 ms settling, the least lag
    "encoder_fast_threshold": 0,
    "pio_sm": 0,
    "microsteps": 256,  # one pulse per library ustep; coarser MRES coarsens the PID error
    "max_step_rate": 1200000,  # pulses/s inside a burst; the average is 90 % of it
    "rsense_ohm": 0.11,  # common on TMC2209 modules
    "full_scale_ma": 1500,  # RMS at 100 %: the uStepper gave about 1.5..1.9 A
    "update_hz": 1000,  # how often the core calls update()
})

JOINT_BUS = {"bus": 0, "sda": 4, "scl": 5}  # the joint's I2C target (config section "i2c")


_INT = 0
_NUM = 1
_SCHEMA = (
    ("uart", _INT, 0, 1), ("uart_tx", _INT, 0, 47), ("uart_rx", _INT, 0, 47),
    ("uart_baud", _INT, 9600, 500000), ("tmc_address", _INT, 0, 3),
    ("encoder_i2c", _INT, 0, 1), ("encoder_sda", _INT, 0, 47), ("encoder_scl", _INT, 0, 47),
    ("encoder_freq", _INT, 10000, 1000000), ("encoder_slow_filter", _INT, 0, 3),
    ("encoder_fast_threshold", _INT, 0, 7),
    ("step", _INT, 0, 47), ("dir", _INT, 0, 47), ("enable", _INT, 0, 47), ("pio_sm", _INT, 0, 11),
    ("microsteps", _INT, 1, 256), ("max_step_rate", _NUM, 1000, SM_FREQ // MIN_PERIOD),
    ("rsense_ohm", _NUM, 0.05, 1.0), ("full_scale_ma", _NUM, 50, 2000), ("update_hz", _NUM, 100, 5000),
)
_PINS = ("uart_tx", "uart_rx", "encoder_sda", "encoder_scl", "step", "dir", "enable")


def _uart_of(pin):
    """UART instance on a GPIO: the RP2040 table (TX on pin % 4 == 0, RX on 1, in blocks
    0,1,1,0,0,1,1,0 of four pins), assumed to continue on the RP2350B's GPIO 30..47."""
    return ((pin // 4 + 1) // 2) % 2


def is_i2c_pin(pin, bus, scl):
    """rp2: GPIO n belongs to I2C (n // 2) % 2, as SDA when n is even, SCL when odd."""
    return pin % 2 == (1 if scl else 0) and (pin // 2) % 2 == bus


def _pins_for(ok):
    return ", ".join("GP%d" % p for p in range(30) if ok(p))


def validate_motor_config(cfg, joint_bus=None):
    """Readable problems with a "pico" motor config dict (empty list: valid).

    `joint_bus` is the joint's I2C target {"bus", "sda", "scl"} (defaults to JOINT_BUS): the
    encoder must use the other I2C block and none of its pins.
    """
    if type(cfg) is not dict:
        return ["the motor config must be an object"]
    errors = []
    known = [spec[0] for spec in _SCHEMA]
    for key in cfg:
        if key != "backend" and key not in known:
            errors.append("unknown key %s (known: %s)" % (key, ", ".join(known)))
    c = dict(DEFAULTS)
    bad = []
    for key, kind, lo, hi in _SCHEMA:
        if key not in cfg:
            continue
        value = cfg[key]
        kinds = (int,) if kind == _INT else (int, float)
        if type(value) is bool or type(value) not in kinds:
            what = "an integer" if kind == _INT else "a number"
            errors.append("%s must be %s, got %r" % (key, what, value))
            bad.append(key)
        elif not lo <= value <= hi:
            errors.append("%s = %r is out of range %s..%s" % (key, value, lo, hi))
            bad.append(key)
        else:
            c[key] = value
    if "microsteps" not in bad and 256 % c["microsteps"]:
        errors.append("microsteps = %r must be a power of two in 1..256" % c["microsteps"])
    uart = c["uart"]
    if c["uart_tx"] % 4 != 0 or _uart_of(c["uart_tx"]) != uart:
        errors.append("uart_tx = %d is not a TX pin of UART%d (use %s)"
                      % (c["uart_tx"], uart, _pins_for(lambda p: p % 4 == 0 and _uart_of(p) == uart)))
    if c["uart_rx"] % 4 != 1 or _uart_of(c["uart_rx"]) != uart:
        errors.append("uart_rx = %d is not an RX pin of UART%d (use %s)"
                      % (c["uart_rx"], uart, _pins_for(lambda p: p % 4 == 1 and _uart_of(p) == uart)))
    bus = c["encoder_i2c"]
    for key, scl, role in (("encoder_sda", False, "SDA"), ("encoder_scl", True, "SCL")):
        pin = c[key]
        if not is_i2c_pin(pin, bus, scl):
            errors.append("%s = %d is not an %s pin of I2C%d (use %s)" % (
                key, pin, role, bus, _pins_for(lambda p: is_i2c_pin(p, bus, scl))))
    joint = JOINT_BUS if joint_bus is None else joint_bus
    if bus == joint["bus"]:
        errors.append("encoder_i2c = %d is the joint bus (I2C%d is the I2C target); use the other one"
                      % (bus, joint["bus"]))
    owners = {joint["sda"]: "the joint bus SDA", joint["scl"]: "the joint bus SCL"}
    for key in _PINS:
        pin = c[key]
        if pin in owners:
            errors.append("%s = %d is already used by %s" % (key, pin, owners[pin]))
        else:
            owners[pin] = key
    if "rsense_ohm" not in bad and "full_scale_ma" not in bad:
        try:
            tmc.current_scale(c["rsense_ohm"], c["full_scale_ma"] / 1000.0)
        except ValueError as exc:
            errors.append("full_scale_ma = %r cannot be set: %s" % (c["full_scale_ma"], exc))
    return errors
