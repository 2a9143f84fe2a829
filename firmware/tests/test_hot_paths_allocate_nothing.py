"""The main loop allocates nothing in steady state, on the Pico backend (issue 9).

Counted under the MicroPython unix port, which boxes floats like the board: the heap bytes that
`service()` allocates, summed over many iterations in each state a joint lives in. Under CPython
(where every int is an object) only the states are exercised. Stall sampling is not covered yet:
the stall detector still computes in floats.
"""

from joint.debug import DebugConsole
from pico_rig import MICROPYTHON, PicoJoint

N = 400


def _zero(joint, what, poll_every=10):
    got = joint.bytes_per_service(N, poll_every)
    assert got is None or got == 0, "%s: %s bytes allocated per service()" % (what, got)


def _moving():
    j = PicoJoint()
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
        j.tick(3000)
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
