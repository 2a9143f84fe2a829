"""The Pico backend's motor configuration: defaults, pins and their validation, and PicoStepper's
construction and begin() (boot only).

A module of its own because nothing here runs after boot: `startup.build` drops it from
`sys.modules` once the joint is built, and its code and tables leave the heap.
"""

from ..core.clock import MonotonicClock
from ..motion.tickramp import POSITIONING, TickRamp
from ..motion.velocity import FixedVelocityEstimator
from . import tmc2209 as tmc
from .as5600 import AS5600, decode_status
from .tmc2209_setup import chopconf, current_scale, tpowerdown, tpwmthrs
from .stepgen import MIN_PERIOD, SM_FREQ, StepGenerator, burst_program, pio_registers

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
            current_scale(c["rsense_ohm"], c["full_scale_ma"] / 1000.0)
        except ValueError as exc:
            errors.append("full_scale_ma = %r cannot be set: %s" % (c["full_scale_ma"], exc))
    return errors


# In usteps/s and usteps/s^2 (converted to the ramp's per-tick Q16 units at construction):
# the TMC5130's largest AMAX/DMAX (0xFFFE at 10 MHz), which the library clamps to and which its
# HARD stop uses, about 11 641 full steps/s^2; its VMAX limit, about 19 538 full steps/s; the
# library constructor's profile.
_MAX_ACCEL = 65534 * 45.4747
_LIB_MAX_VEL = 0x7FFE00 * 0.596046
_DEFAULT_VEL = 100 * 256
_DEFAULT_ACCEL = 2000 * 256
_BOOT_PERCENT = 40  # setup() sets run and hold current to 40 % whatever it is passed
_POWERDOWN_S = 0.524  # the TMC5130's reset TPOWERDOWN (20) at 10 MHz, kept for the same feel
_STEALTH_MAX = 2000.0  # usteps/s: the library's TPWMTHRS=5000 at 10 MHz


def resolved(motor_cfg):
    """`motor_cfg` with DEFAULTS filling the gaps; ValueError naming every problem."""
    problems = validate_motor_config(motor_cfg)
    if problems:
        raise ValueError("; ".join(problems))
    c = dict(DEFAULTS)
    c.update(motor_cfg)
    return c


def build_stepper(cls, motor_cfg, clock):
    """PicoStepper.from_config: the real objects from a motor config dict (DEFAULTS fill the gaps)."""
    from . import i2c_registers

    c = resolved(motor_cfg)
    import machine
    import rp2

    Pin = machine.Pin
    char_ms = 1 + 10000 // c["uart_baud"]
    uart = machine.UART(c["uart"], baudrate=c["uart_baud"], tx=Pin(c["uart_tx"]), rx=Pin(c["uart_rx"]),
                        timeout=2 + 3 * char_ms, timeout_char=2 + 3 * char_ms)
    i2c = machine.I2C(c["encoder_i2c"], sda=Pin(c["encoder_sda"]), scl=Pin(c["encoder_scl"]),
                      freq=c["encoder_freq"])
    enable = Pin(c["enable"], Pin.OUT, value=1)  # ENN high: bridges off until begin()
    sm = rp2.StateMachine(c["pio_sm"], burst_program(), freq=SM_FREQ,
                          sideset_base=Pin(c["step"]), out_base=Pin(c["dir"]))
    sm.active(1)
    return cls(tmc.TMC2209(uart, c["tmc_address"]), AS5600(i2c, regs=i2c_registers(c["encoder_i2c"])),
               StepGenerator(sm, c["microsteps"], c["max_step_rate"], SM_FREQ, *pio_registers(c["pio_sm"])),
               enable, clock,
               c["update_hz"], c["rsense_ohm"], c["full_scale_ma"],
               c["encoder_slow_filter"], c["encoder_fast_threshold"])


def init_stepper(m, driver, encoder, steps, enable, clock, update_hz, rsense_ohm, full_scale_ma,
                 encoder_slow_filter, encoder_fast_threshold):
    """PicoStepper.__init__ (see there): the state `m` keeps, set up once."""
    m._drv = driver
    m._enc = encoder
    m._steps = steps
    m._enable = enable
    m._clock = clock or MonotonicClock()
    m._microsteps = 256 // steps.upp
    m._enc_conf = (encoder_slow_filter, encoder_fast_threshold)
    m._vsense, m._cs_max = current_scale(rsense_ohm, full_scale_ma / 1000.0)
    # The 1 kHz path is integers only (a float is a heap object on the board): the ramp runs
    # in whole ticks of `_tick_us`, speeds in Q16 usteps per tick, accelerations per tick^2.
    rate = int(update_hz)
    m._rate = rate
    m._vmax_den = 3 * rate  # set_rpm: 51200 / 60 usteps/s per rpm = 2560 / (3 * rate) per tick
    m._tick_us = 1000000 // rate
    m._ramp = TickRamp()
    m._vel = FixedVelocityEstimator(rate)
    # The 1 kHz path works on the state arrays themselves (ramp, estimator, pulse counters).
    m._rs = m._ramp.s
    m._vs = m._vel.s
    m._ss = steps.s
    m._sm = steps._sm
    m._pio = steps.pio
    m._es = encoder.s
    num, den = 3 * rate, 2560
    while den % 2 == 0 and num % 2 == 0:
        num //= 2
        den //= 2
    while den % 5 == 0 and num % 5 == 0:
        num //= 5
        den //= 5
    m._rpm_num, m._rpm_den = num, den  # ramp Q16 usteps/tick -> rpm Q16 = * num / den
    m._per_tick = 65536 / rate  # usteps/s -> Q16 usteps/tick (configuration time only)
    m._per_tick2 = 65536 / (rate * rate)
    m._vmax_limit = m._v(min(_LIB_MAX_VEL, steps.max_usteps_per_s()))
    m._max_accel = m._a(_MAX_ACCEL)
    m._vmax = min(m._v(_DEFAULT_VEL), m._vmax_limit)
    m._amax = m._a(_DEFAULT_ACCEL)
    m._dmax = m._amax
    m._threshold = 10
    m._closed_loop = False
    m._error = 0
    m._stopping = False
    m._irun = m._ihold = tmc.percent_to_cs(_BOOT_PERCENT, m._cs_max)
    m._pwmconf = 0
    m._ready = False
    m._last_us = 0
    # update()'s references, one tuple load instead of twelve attribute loads (~2 us each)
    m._hot = (m._ss, m._sm, m._pio, m._rs, m._es, encoder.regs, encoder.buf, m._vs,
              m._clock.ticks_us, m._clock.ticks_diff, m._clock.ticks_add, m._tick_us)
    m.fault = None  # last UART error after begin(), for diagnostics
    m.faults = 0


def begin_stepper(m):
    """PicoStepper.begin (see there), run by the boot task."""
    drv = m._drv
    version = drv.read(tmc.IOIN) >> 24
    if version != tmc.VERSION:
        raise tmc.TMCError("TMC2209 at node %d reports version 0x%02x, expected 0x21"
                           % (drv.node, version))
    chop = chopconf(drv.read(tmc.CHOPCONF), m._microsteps, m._vsense)
    m._pwmconf = tmc.pwmconf(drv.read(tmc.PWMCONF), tmc.FREEWHEEL_SHORT_LS)
    before = drv.read(tmc.IFCNT)
    writes = (
        (tmc.GSTAT, 7),  # clear reset/error flags (write 1 to clear)
        (tmc.GCONF, tmc.gconf(False)),
        (tmc.CHOPCONF, chop),
        (tmc.PWMCONF, m._pwmconf),
        (tmc.TPOWERDOWN, tpowerdown(_POWERDOWN_S)),
        (tmc.TPWMTHRS, tpwmthrs(_STEALTH_MAX)),
        (tmc.IHOLD_IRUN, tmc.ihold_irun(m._ihold, m._irun)),
    )
    for reg, value in writes:
        drv.write(reg, value)
    counted = (drv.read(tmc.IFCNT) - before) & 0xFF
    if counted != len(writes):
        raise tmc.TMCError("TMC2209 accepted %d of %d configuration writes (IFCNT)"
                           % (counted, len(writes)))
    enc = m._enc
    detected, weak, strong = decode_status(enc.status())
    if not detected or weak or strong:
        problem = "not detected" if not detected else "too weak" if weak else "too strong"
        raise OSError("AS5600: magnet %s (check the magnet and its distance)" % problem)
    enc.configure(m._enc_conf[0], m._enc_conf[1])
    enc.start()
    m._encoder_error = enc.raw - m._corrected(enc.raw)
    m._vel.reset()
    m._steps.shift(-m._steps.position)
    ramp = m._ramp
    ramp.set_position(m._steps.commanded)
    ramp.v = 0
    ramp.mode = POSITIONING
    ramp.xtarget = ramp.xactual()
    ramp.vmax = 0  # the library leaves VMAX at 0 until the first motion call
    ramp.amax = m._amax
    ramp.dmax = m._dmax
    m._closed_loop = False
    m._error = 0
    m._stopping = False
    if m._enable is not None:
        m._enable.value(0)
    m._last_us = m._clock.ticks_us()
    m._ready = True
