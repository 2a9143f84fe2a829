"""The main loop allocates nothing in steady state, on the Pico backend (issue 9).

Counted under the MicroPython unix port, which boxes floats like the board: the heap bytes that
`service()` allocates, summed over many iterations in each state a joint lives in. Under CPython
(where every int is an object) only the states are exercised. The supervision runs on the shipped
configs (the tracking stall detector, the homing monitor, the deadman in every mode and its quick
stop) and the original stall detector, the schema default, with its console trace on too.
"""

import gc

from joint.config import schema as config
from joint.motion.hal import MAGNET_OK
from joint.spec import protocol as P
from joint.console.debug import DebugConsole
from pico_rig import MICROPYTHON, PicoJoint

N = 400


def _zero(joint, what, poll_every=10):
    got = joint.bytes_per_service(N, poll_every)
    if got is None:  # CPython: the same iterations, uncounted
        joint.tick(N, poll_every=poll_every)
    assert got is None or got == 0, "%s: %s bytes allocated per service()" % (what, got)


def _moving(cfg=None):
    j = PicoJoint(cfg=cfg)
    j.command("SETUP", 40, 20, 0, 0)
    j.tick(2)
    return j


def test_idle_and_holding_allocate_nothing():
    j = PicoJoint()
    _zero(j, "idle after boot", poll_every=0)
    j.command("SETUP", 40, 20, 0, 0)
    j.tick(2)
    _zero(j, "enabled and holding")


def test_turning_at_any_speed_allocates_nothing():
    j = _moving()
    for rpm in (0.5, 30.0, -120.0, 334.0, 1000.0):
        j.command("SETRPM", rpm)
        _zero(j, "accelerating to %s rpm" % rpm)
        j.tick(3000, poll_every=10)  # a polling host keeps the deadman fed
        _zero(j, "turning at %s rpm" % rpm)
    assert j.core.qd_set != 0 and not j.motor.position_reached()


def test_a_host_streaming_setpoints_costs_no_allocation():
    j = _moving()
    if not MICROPYTHON:
        return
    import gc
    total = 0
    for i in range(200):
        j.command("SETRPM", 10.0 + i * 0.5)  # the IRQ queues it; service() applies it
        j.clock.advance(1000)
        gc.collect()
        before = gc.mem_alloc()
        j.core.service()
        total += gc.mem_alloc() - before
    assert total == 0, "%d bytes over 200 streamed SETRPM" % total


def test_positioning_allocates_nothing():
    j = _moving()
    j.command("MOVEANGLE", 3600.0)
    j.tick(2)
    _zero(j, "positioning")
    assert j.core.positioning


def test_homing_allocates_nothing():
    j = _moving()
    j.command("HOME", 1, 10, 200, 30)
    j.tick(600)  # past the settle time: driving toward the stop
    _zero(j, "homing")
    assert j.core.task_name == "HOME"


def test_reading_the_magnet_status_allocates_nothing():
    """A HOME's first check (MotorHAL.magnet, the AS5600's STATUS) runs in the main loop's task."""
    j = _moving()
    j.motor.magnet()  # warm: the first call may intern
    if MICROPYTHON:
        gc.collect()
        before = gc.mem_alloc()
        health = j.motor.magnet()
        assert gc.mem_alloc() - before == 0, gc.mem_alloc() - before
    else:
        health = j.motor.magnet()
    assert health == MAGNET_OK


def test_deadman_watching_and_the_idle_console_allocate_nothing():
    j = _moving()
    j.command("SETRPM", 60.0)
    console = DebugConsole(j.core, lambda buf: 0, j.lines.append)
    console.poll()
    core = j.core
    if MICROPYTHON:
        import gc
        total = 0
        for _ in range(N):
            j.clock.advance(1000)
            j.host_poll()
            gc.collect()
            before = gc.mem_alloc()
            core.service()
            console.poll()
            total += gc.mem_alloc() - before
        assert total == 0, "%d bytes with the deadman watching and the console idle" % total
    else:
        for _ in range(N):
            j.host_poll()
            j.tick()
            console.poll()
    assert core.qd_set != 0, "the deadman must not fire while the host polls"


def _shipped(joint="J1"):
    """A joint on its shipped configuration (tracking stall detector), enabled."""
    cfg = config.load("firmware/joint/config/%s.json" % joint)
    assert cfg.valid and cfg.stall.detector == "tracking", cfg.errors
    return _moving(cfg)


def test_stall_sampling_with_the_tracking_detector_allocates_nothing():
    j = _shipped()
    j.command("ENABLESTALLGUARD", 6)
    j.command("SETRPM", 100.0)
    j.tick(1000, poll_every=10)
    _zero(j, "turning with the tracking detector sampling")
    assert j.core.stallguard and j.core.track.speed != 0, "the detector must be sampling a motion"
    assert not j.core.flags & P.FLAG_STALL


def test_stall_sampling_with_the_slow_contact_detector_allocates_nothing():
    j = _shipped("J2")  # the joint that ships it (load_angle.py)
    assert j.core.load is not None
    j.command("ENABLESTALLGUARD", 12)
    j.command("SETRPM", 30.0)
    j.tick(6000, poll_every=10)  # past a motor turn: the detector judges against its baseline
    _zero(j, "turning with the slow-contact detector judging")
    assert j.core.load._baseline[0] != 0 and j.core.load._baseline[-1] != 0, "a whole turn must be learned"
    assert not j.core.flags & P.FLAG_STALL


def test_stall_sampling_with_the_original_detector_allocates_nothing():
    j = _moving()  # the schema default: a joint without a config file
    assert j.cfg.stall.detector == "original"
    j.command("ENABLESTALLGUARD", 6)
    j.command("SETRPM", 100.0)
    j.tick(1000, poll_every=10)
    j.core.stall.raw = -1
    _zero(j, "turning with the original detector sampling")
    assert j.core.stall.raw != -1, "the detector must sample during the counted iterations"
    assert j.core.stallguard and j.core.stall.speed != 0 and not j.core.flags & P.FLAG_STALL



def test_the_trace_on_the_console_allocates_nothing():
    j = _moving()
    j.command("ENABLESTALLGUARD", 6)
    j.command("SETRPM", 100.0)
    printed = [0, 0]  # lines, bytes: a writer that keeps nothing, as USB takes the bytes

    def write(line):
        printed[0] += 1
        printed[1] += len(line)
    console = DebugConsole(j.core, lambda buf: 0, write)
    console.execute("trace", ["on"])
    j.tick(1000, poll_every=10)
    lines = printed[0]
    _zero(j, "turning with the trace on")
    assert printed[0] - lines >= N // 10 - 1, "one line per 10 ms sample during the counted iterations"
    assert printed[1] > 30 * printed[0]

def test_homing_on_the_shipped_config_allocates_nothing():
    j = _shipped()
    j.command("WATCHDOG", 50)  # our host's: the deadman watches the homing too
    j.command("HOME", 1, 10, 200, 30)
    j.tick(600, poll_every=10)  # past the settle time: driving, the monitor sampling
    _zero(j, "homing with the monitor and the deadman watching")
    assert j.core.task_name == "HOME" and j.core.homing.outcome == 0  # still running


def test_the_deadman_in_every_mode_allocates_nothing():
    j = _shipped()
    j.command("WATCHDOG", 50)
    j.command("MOVEANGLE", 36000.0)
    j.tick(2, poll_every=1)
    _zero(j, "positioning with the watchdog")
    j.command("SETRPM", 60.0)
    j.tick(500, poll_every=10)
    _zero(j, "velocity with the watchdog")
    assert j.core.qd_set != 0 and not j.core.flags & P.FLAG_NOTENABLED
    j.command("STOP", 0)
    j.tick(1000, poll_every=10)  # the ramp down from 60 rpm, with the host watching
    _zero(j, "holding still with the watchdog, the host quiet", poll_every=0)
    assert not j.core.flags & P.FLAG_NOTENABLED, "holding still is not motion"


def test_the_deadman_quick_stop_allocates_nothing_after_its_decision():
    j = _shipped()
    j.command("WATCHDOG", 50)
    j.command("SETRPM", 300.0)
    j.tick(1500, poll_every=10)  # at speed
    core = j.core
    while not core.flags & P.FLAG_NOTENABLED:  # silence: the decision (its log line allocates)
        j.tick()
    assert core._safe_pending and j.motor.driver_rpm() != 0, "the quick stop must be braking"
    _zero(j, "braking at stop_deceleration, then holding", poll_every=0)
    assert j.motor.driver_rpm() == 0 and not core._safe_pending
