"""Joint controller core: register semantics, flags, blocking commands, stall detection, deadman.

`JointController` composes the core's contexts, one module each:

* `irq.py` (IRQ path: `on_frame`, `reply_into`, `host_seen`): never allocates; validates frames,
  updates flags, queues commands, serves replies packed in advance;
* `loop.py` (main loop: `service`): drains the queue into the motor HAL through the register
  handlers of `handlers.py`, steps the blocking tasks of `tasks.py` (boot, HOME,
  CHECKORIENTATION), runs the supervision of `supervise.py` (stall detection, deadman) and
  refreshes the reply caches.

No hardware module is imported here: the HAL, clock, logger and IRQ masking are injected.
"""

import struct

from .fixed import STEPS_Q, to_q
from .handlers import Handlers
from .irq import COUNTER_MASK, IrqPath
from .loop import MainLoop
from .protocol import (
    ACK, CHECKORIENTATION, CLEARSTALL, DISABLECLOSEDLOOP, DISABLESTALLGUARD,
    ENABLECLOSEDLOOP, ENABLESTALLGUARD, FLAG_BUSY, FLAGS_AT_BOOT, HOME, IDENTITY, MOVEANGLE,
    MOVESTEPS, MOVETOANGLE, PING, PROTOCOL, PROTOCOL_VERSION, SETBRAKEMODE, SETCURRENT, SETHOLDCURRENT,
    SETMAXACCELERATION, SETMAXDECELERATION, SETMAXVELOCITY, SETRPM, SETUP, SPEC_HASH, WATCHDOG,
)
from .regtable import RegisterTable
from .homing import HomingMonitor
from .stall import StallDetector
from .supervise import DETECTOR_NAMES, Supervisor
from .tracking import TrackingDetector
from .tasks import Tasks
from .version import FIRMWARE_VERSION

__all__ = ("COUNTER_MASK", "JointController")

def _no_irq_off():
    return 0


def _no_irq_on(state):
    pass


class JointController(IrqPath, MainLoop, Handlers, Tasks, Supervisor):
    """The firmware of one joint, independent of the I2C peripheral and the motor backend."""

    def __init__(self, hal, clock, cfg, log, critical=None):
        self.hal = hal
        self.clock = clock
        self.cfg = cfg
        self.log = log
        self._irq_off, self._irq_on = critical or (_no_irq_off, _no_irq_on)
        self.flags = FLAGS_AT_BOOT | FLAG_BUSY
        self.ready = False
        self.disabled = not cfg.valid
        # Setpoints and modes (main loop).
        self.drive_current = 0
        self.hold_current = 0
        self.qd_set = 0  # rpm Q16
        self.q_set = 0  # degrees Q12
        self.positioning = False
        self.closed_loop = False
        self.inverted = False
        self.stallguard = False
        self.stall = StallDetector(cfg.stall)
        st = cfg.stall
        self.track = TrackingDetector(st.track_base, st.track_tau_ms, st.track_window, st.track_confirm,
                                      st.track_sample_ms, st.track_cap, st.track_slope_q8)
        self.detector = DETECTOR_NAMES.index(st.detector) if st.detector in DETECTOR_NAMES else 0
        self.homing = HomingMonitor(cfg.homing, st)
        # HOME sensitivity noise floor, integer for the IRQ: threshold + speed * per_rpm (Q10).
        self._homing_floor = int(cfg.boot.control_threshold)
        self._homing_floor_q = int(cfg.homing.floor_per_rpm * 1024 + 0.5)
        # Deadman: 0 = the original's (velocity only, cfg.deadman_ms); WATCHDOG sets every mode.
        self.watchdog_ms = 0
        self._deadman_ms = cfg.deadman_ms
        self._deadman_us = cfg.deadman_ms * 1000  # the main loop's test before calling the deadman
        # Degrees Q12 from the encoder's zero (set where the rotor rested after homing) to the end
        # stop's deepest point: the host's angle is the encoder's plus this.
        self.zero_offset = 0
        self._safe_pending = False
        # The host's acceleration limits, restored after a deadman stop, and the deadman's
        # quick-stop deceleration: full steps/s^2 Q4, converted here, once.
        self.max_acceleration = self.max_deceleration = to_q(cfg.boot.max_acceleration, STEPS_Q)
        self.stop_deceleration = to_q(cfg.stop_deceleration, STEPS_Q)
        self.trace = None  # main loop: called with the detector after every stall-detection sample
        # Reply caches: bytes of every readable register, packed ahead of the read.
        self.registers = RegisterTable()  # what the joint keeps of the spec past boot
        self._cache = [None] * len(self.registers.reply_size)  # by address, as far as the spec goes
        for addr, size in enumerate(self.registers.reply_size):
            if size:
                self._cache[addr] = bytearray(size)
        self._cache[PING][0] = ACK
        self._cache_values = [0, 0, 0, 0]  # what the float caches hold (HAL units)
        self._cache_turn = 0  # counts iterations: which of the slower caches is refreshed next
        struct.pack_into("<BBBBBI", self._cache[IDENTITY], 0, PROTOCOL_VERSION, FIRMWARE_VERSION[0],
                         FIRMWARE_VERSION[1], FIRMWARE_VERSION[2], cfg.joint_id, SPEC_HASH)
        # IRQ-side state: the reply the next read gets, the command queue, counters.
        self._init_irq_tables()
        self._q_in = 0  # written by the IRQ path only
        self._q_out = 0  # written by the main loop only
        self._blocking_in = 0  # blocking commands accepted (IRQ) ...
        self._blocking_out = 0  # ... and taken from the queue (main loop)
        self._blocking_stops = 0  # stop epoch when the latest blocking command was accepted
        self.transactions = 0
        self._ticks_us = clock.ticks_us  # bound once: the IRQ path calls it
        self.host_us = clock.ticks_us()
        # Epochs (8 bits). `stops`: STOP frames (IRQ); a task or queued blocking command from an
        # older epoch is cancelled. `halts`: whatever stopped the motor (STOP in the IRQ, stall or
        # deadman in the main loop); queued motion from an older epoch is not applied.
        # `stall_rearms`: frames that cleared STALL, so a stall decided before one is dropped.
        self.stops = 0
        self.halts = 0
        self.stall_rearms = 0
        self._stops_seen = 0
        self._motion_allowed = False
        self.rejects = 0
        self._logged_rejects = 0
        # Main-loop bookkeeping.
        now = clock.ticks_ms()
        self._seen_transactions = 0
        self._last_host_us = self.host_us
        self._next_stall_ms = now
        self._stall_period_ms = int(cfg.stall.sample_time * 1000 + 0.5)
        self._next_track_ms = now
        self._next_sample_ms = now  # the earlier of the two
        self._task = None
        self.task_name = None
        self._task_stops = 0  # the stop epoch the running task belongs to
        self._task_wake = now
        self._handlers = {
            SETUP: self._setup, SETRPM: self._set_rpm, MOVESTEPS: self._move_steps,
            MOVEANGLE: self._move_angle, MOVETOANGLE: self._move_to_angle,
            SETCURRENT: self._set_current, SETHOLDCURRENT: self._set_hold_current,
            SETMAXACCELERATION: self._set_max_acceleration,
            SETMAXDECELERATION: self._set_max_deceleration, SETMAXVELOCITY: self._set_max_velocity,
            ENABLESTALLGUARD: self._enable_stallguard, DISABLESTALLGUARD: self._disable_stallguard,
            CLEARSTALL: self._clear_stall, SETBRAKEMODE: self._set_brake_mode,
            ENABLECLOSEDLOOP: self._enable_closed_loop, DISABLECLOSEDLOOP: self._disable_closed_loop,
            CHECKORIENTATION: self._check_orientation, HOME: self._home,
            PROTOCOL: self._select_protocol, WATCHDOG: self._set_watchdog,
        }
        self.protocol_request = 0  # a PROTOCOL write (main loop); the protocol switch (v2.py) acts on it
        if self.disabled:
            for problem in cfg.errors:
                log.error(problem)
            log.error("invalid configuration: joint disabled, commands are rejected")
            self.flags = FLAGS_AT_BOOT
            self.ready = True
        else:
            self._start_task("boot", self._boot())

    def set_critical(self, critical):
        """The (disable, enable) interrupt pair guarding state shared with the IRQ path; None:
        nothing to guard (protocol v2: no Python IRQ, and the I2C interrupt must never be held
        off while a transaction is in progress, see ProtocolSwitch)."""
        self._irq_off, self._irq_on = critical or (_no_irq_off, _no_irq_on)

    def _select_protocol(self, q, off):
        self.protocol_request = q[off]


def _flatten(cls):
    """Copy the mixins' methods into `cls`'s own dictionary (the first base that defines a name
    wins, as in the method resolution order). MicroPython looks a method up base after base on
    every call: about 40 us on the chip for one of the last mixin's, 5 us in the class itself."""
    own = [name for name in cls.__dict__]
    for base in reversed(cls.__bases__):
        for name, value in base.__dict__.items():
            if not name.startswith("__") and name not in own:
                setattr(cls, name, value)
    return cls


_flatten(JointController)
