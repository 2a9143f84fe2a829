"""JointController's construction, boot only (startup.BOOT_ONLY): the board forgets this code once the
joint is built; the controller keeps only the state it made.

Who owns which state. Every attribute below is created here (`init`, `irq_init.init`); after boot
each is written only by the context it is listed under (tests/test_firmware_state_owners.py reads
the code of each context and checks it against these tables):

    IRQ          irq.py: on_frame, reply_wire, host_seen (never allocates)
    MAIN_LOOP    loop.py, handlers.py: draining the queue, applying commands, the reply caches
    SUPERVISION  supervise.py: stall detection, the deadman
    TASKS        tasks.py: the blocking tasks (boot, HOME, CHECKORIENTATION)
    MAIN_SHARED  written by more than one of the main loop's parts (one thread: no guard needed)
    IRQ_SHARED   what the IRQ context and the main loop share: written by one, read by the other
                 (or, for `flags` and `halts`, written by both inside the critical section)
    TABLE_IRQ, TABLE_MAIN  the frame table's state bytes each side writes (the queue counters, the
                 blocking commands' and the running task's epochs, LASTERROR's record)

Everything else `init` sets (hal, clock, cfg, log, the configuration's constants, the frame
table's other bytes) is written once here and only read after.
"""

import struct
from array import array

from ..motion.fixed import ANGLE_Q, STEPS_Q, store_q, to_q
from ..detect.homing import HomingMonitor
from .irq_init import init as init_irq
from ..spec.protocol import (
    ACK, CHECKORIENTATION, CLEARSTALL, DISABLECLOSEDLOOP, DISABLESTALLGUARD, ENCODERZERO,
    ENABLECLOSEDLOOP, ENABLESTALLGUARD, FLAG_BUSY, FLAGS_AT_BOOT, HOME, IDENTITY, MOVEANGLE,
    MOVESTEPS, MOVETOANGLE, PING, PROTOCOL, PROTOCOL_VERSION, SETBRAKEMODE, SETCURRENT, SETHOLDCURRENT,
    SETMAXACCELERATION, SETMAXDECELERATION, SETMAXVELOCITY, SETRPM, SETUP, SPEC_HASH, WATCHDOG,
)
from ..spec.regtable import RegisterTable
from ..detect.stall import StallDetector
from .supervise import DETECTOR_NAMES
from ..detect.tracking import TrackingDetector
from ..spec.version import FIRMWARE_VERSION

IRQ = ("_reply_wire", "_reply_err", "transactions", "host_us", "stops")
MAIN_LOOP = ("_cache_turn", "_logged_rejects", "_motion_allowed", "_stops_seen", "disabled", "ready",
             "closed_loop", "drive_current", "hold_current", "max_acceleration", "max_deceleration",
             "q_set", "stall", "stallguard", "target_known", "watchdog_ms")
SUPERVISION = ("detector", "_coasting", "_arrived")
TASKS = ("_task_wake", "inverted", "zero_offset")
MAIN_SHARED = ("flags", "halts", "positioning", "qd_set", "_task", "task_name", "_safe_pending",
               "_next_sample_ms", "_next_stall_ms", "_next_track_ms")
IRQ_SHARED = ("flags", "halts", "host_us", "stops", "transactions")
# The rest of the state the IRQ context and the main loop share is bytes of the frame table
# (`_ftab`, irq_init.py; the judge reads a byte there without an attribute lookup): by writer,
# the names of irq_init's offsets. HALTS is written by both, inside the critical section.
TABLE_IRQ = ("STOPS", "HALTS", "BLOCK_IN", "BLOCK_STOPS", "Q_IN", "REARMS", "LASTERROR_WIRE")
TABLE_MAIN = ("DISABLED", "HALTS", "BLOCK_OUT", "Q_OUT", "TASK", "TASK_STOPS")


def init(core, hal, clock, cfg, log, critical):
    """Set up `core` (a JointController) for motor `hal`, `clock`, configuration `cfg`, logger `log`."""
    core.hal = hal
    core.clock = clock
    core.cfg = cfg
    core.log = log
    core.set_critical(critical)
    core.flags = FLAGS_AT_BOOT | FLAG_BUSY
    core.ready = False
    core.disabled = not cfg.valid
    # Setpoints and modes (main loop).
    core.drive_current = 0
    core.hold_current = 0
    core.qd_set = 0  # rpm Q16
    core.q_set = 0  # degrees Q12
    core.positioning = False
    core.target_known = False  # the running positioning move ends at q_set (MOVETOANGLE)
    core.closed_loop = False
    core.inverted = False
    core.stallguard = False
    core.stall = StallDetector(cfg.stall)
    st = cfg.stall
    core.track = TrackingDetector(st.track_base, st.track_tau_ms, st.track_window, st.track_confirm,
                                  st.track_sample_ms, st.track_cap, st.track_slope_q8)
    core.load = None  # the slow-contact detector, on joints that configure it (imported then only)
    if st.load_limit:  # imported only by a joint that uses it (J2): 3 KB of heap
        from ..detect.load_angle import LoadAngleDetector
        core.load = LoadAngleDetector(st.load_limit, st.load_confirm, st.load_clip)
    core.detector = DETECTOR_NAMES.index(st.detector) if st.detector in DETECTOR_NAMES else 0
    core.homing = HomingMonitor(cfg.homing, st)
    # Deadman: 0 = the original's (velocity only, cfg.deadman_ms); WATCHDOG sets every mode.
    core.watchdog_ms = 0
    core._deadman_ms = cfg.deadman_ms
    core._deadman_us = cfg.deadman_ms * 1000  # the main loop's test before calling the deadman
    # Degrees Q12 from the encoder's zero (set where the rotor rested after homing) to the end
    # stop's deepest point: the host's angle is the encoder's plus this.
    core.zero_offset = 0
    core._safe_pending = False
    core._coasting = False  # the ramp after commanded motion, until the motor first stands
    core._arrived = False  # the move to q_set came to its target: holding (supervise.py)
    # The host's acceleration limits, restored after a deadman stop, and the deadman's
    # quick-stop deceleration: full steps/s^2 Q4, converted here, once.
    core.max_acceleration = core.max_deceleration = to_q(cfg.boot.max_acceleration, STEPS_Q)
    core.stop_deceleration = to_q(cfg.stop_deceleration, STEPS_Q)
    core.trace = None  # main loop: called with the detector after every stall-detection sample
    # Reply caches: bytes of every readable register, packed ahead of the read.
    core.registers = RegisterTable()  # what the joint keeps of the spec past boot
    core._cache = [None] * len(core.registers.reply_size)  # by address, as far as the spec goes
    for addr, size in enumerate(core.registers.reply_size):
        if size:
            core._cache[addr] = bytearray(size)
    core._cache[PING][0] = ACK
    # What the float caches hold, in HAL units: the angle (Q12, from home), the encoder speed and the
    # driver speed (rpm Q16), the PID error (usteps); v2.py packs the first two into its state block.
    core.reply_values = [0, 0, 0, 0]
    core._cache_turn = 0  # counts iterations: which of the slower caches is refreshed next
    struct.pack_into("<BBBBBI", core._cache[IDENTITY], 0, PROTOCOL_VERSION, FIRMWARE_VERSION[0],
                     FIRMWARE_VERSION[1], FIRMWARE_VERSION[2], cfg.joint_id, SPEC_HASH)
    # IRQ-side state: the reply the next read gets, the command queue, counters; the frame table
    # holds HOME's sensitivity noise floor, integer: threshold + speed * per_rpm (Q10).
    init_irq(core, int(cfg.boot.control_threshold), int(cfg.homing.floor_per_rpm * 1024 + 0.5))
    core.transactions = 0
    core._ticks_us = clock.ticks_us  # bound once: the IRQ path calls it
    core.host_us = clock.ticks_us()
    # Epochs (8 bits). `stops`: STOP frames (IRQ); a task or queued blocking command from an
    # older epoch is cancelled. `halts`: whatever stopped the motor (STOP in the IRQ, stall or
    # deadman in the main loop); queued motion from an older epoch is not applied. (The frame
    # table counts the frames that cleared STALL, the queue, the blocking commands: irq_init.py.)
    core.stops = 0
    core.halts = 0
    core._stops_seen = 0
    core._motion_allowed = False
    core._logged_rejects = 0  # the rejection count's low byte when the main loop last logged one
    # Main-loop bookkeeping.
    now = clock.ticks_ms()
    core._next_stall_ms = now
    core._stall_period_ms = int(cfg.stall.sample_time * 1000 + 0.5)
    core._next_track_ms = now
    core._next_sample_ms = now  # the earlier of the two
    core._task = None  # its stop epoch is in the frame table (the IRQ reads it)
    core.task_name = None
    core._task_wake = now
    core._handlers = {
        SETUP: core._setup, SETRPM: core._set_rpm, MOVESTEPS: core._move_steps,
        MOVEANGLE: core._move_angle, MOVETOANGLE: core._move_to_angle,
        SETCURRENT: core._set_current, SETHOLDCURRENT: core._set_hold_current,
        SETMAXACCELERATION: core._set_max_acceleration,
        SETMAXDECELERATION: core._set_max_deceleration, SETMAXVELOCITY: core._set_max_velocity,
        ENABLESTALLGUARD: core._enable_stallguard, DISABLESTALLGUARD: core._disable_stallguard,
        CLEARSTALL: core._clear_stall, SETBRAKEMODE: core._set_brake_mode,
        ENABLECLOSEDLOOP: core._enable_closed_loop, DISABLECLOSEDLOOP: core._disable_closed_loop,
        CHECKORIENTATION: core._check_orientation, HOME: core._home,
        PROTOCOL: core._select_protocol, WATCHDOG: core._set_watchdog,
    }
    core.protocol_request = 0  # a PROTOCOL write (main loop); the protocol switch (v2.py) acts on it
    if core.disabled:
        for problem in cfg.errors:
            log.error(problem)
        log.error("invalid configuration: joint disabled, commands are rejected")
        core.flags = FLAGS_AT_BOOT
        core.ready = True
    else:
        core._start_task("boot", _boot(core), core.stops)


def encoder_table(values, counts_per_rev):
    """The HAL's form of a calibration table (MotorHAL._corrected): `values`, the encoder's error in
    motor millidegrees at len(values) equally spaced angles of its turn (a power of two, at most
    `counts_per_rev`), as array("h") [shift, errors in counts..., the first again], an angle being
    2**shift counts."""
    n = len(values)
    table = array("h", bytes(2 * n + 4))
    while n << table[0] < counts_per_rev:
        table[0] += 1
    for i in range(n):
        table[i + 1] = (values[i] * counts_per_rev + (180000 if values[i] >= 0 else -180000)) // 360000
    table[n + 1] = table[1]
    return table


def _boot(core):
    """The boot task, the original setup(): closed loop, boot limits, orientation check, then
    freewheel. This generator is the last holder of this module: it goes once the task ends."""
    hal = core.hal
    boot = core.cfg.boot
    correction = core.cfg.encoder.correction
    hal.set_encoder_correction(encoder_table(correction, hal._encoder_cpr) if correction else None)
    hal.begin()
    store_q(core._cache[ENCODERZERO], hal.encoder_zero(), ANGLE_Q)  # tasks.py's at a homing
    hal.enable_closed_loop()
    core.closed_loop = True
    accel = to_q(boot.max_acceleration, STEPS_Q)
    hal.set_max_acceleration(accel)
    hal.set_max_deceleration(accel)
    hal.set_max_velocity(to_q(boot.max_velocity, STEPS_Q))
    hal.set_control_threshold(to_q(boot.control_threshold, 0))
    yield from core._orientation(to_q(boot.orientation_check, ANGLE_Q))
    hal.stop(True)
    hal.set_current(0)
    hal.set_hold_current(0)
    hal.set_brake_mode(0)
    core._set_flags(FLAGS_AT_BOOT)
    core.ready = True
    core.log.info("%s ready at 0x%02x" % (core.cfg.joint, core.cfg.address))
