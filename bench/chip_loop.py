"""Runs ON the emulated Pico (bench/chip_bench.py puts it in flash as /chip_loop.mpy): the deployed joint's
own `app.run()`, unmodified, with `JointController.service` and `DebugConsole.poll` wrapped to
measure the main loop. Nothing here is part of the firmware; the wrappers do not allocate. Before
measuring it hands the core a SETUP frame, as the host's I2C transaction would, so the host's
cycling SETRPM (bench/chip_bus.py host_cycle) turns the motor: the joint is moving.

    import chip_loop; chip_loop.run(5000)

`gc.mem_alloc()` walks the whole heap (about 9 ms on the chip), so it cannot run every iteration
without changing what is measured. Two phases, in one run of the joint:
1. allocation: after `SETTLE_CALLS` calls (the enable's one-off work, such as logging the host's
   SETRPM refused before it), `ALLOC_CALLS` service() calls, each between two mem_alloc() readings; the figure
   is the mean over calls during which no collection ran;
2. after `CATCH_UP_CALLS` untimed calls (the loop back on its schedule), timing, `duration_ms`:
   service() time per call, iteration time (service start to service start), loop rate (with
   `trace`, TIMED_MARK on the console first). A collection is found by mem_alloc() falling, read
   only after an iteration longer than `STALL_US` (the iteration after that reading is left out):
   its pause is that iteration less the median one. Collections that stall the loop less than STALL_US are counted
   at the end but give no pause figure.
"""

import gc
import time
from array import array

from micropython import const

from joint import app
from joint.core import controller as core
from joint.console import debug
from joint.spec.protocol import ENABLESTALLGUARD, SETUP  # ints: holding the module would keep the spec the board drops after boot

ALLOC_CALLS = const(40)
SETTLE_CALLS = const(200)
CATCH_UP_CALLS = const(20)
STALL_US = const(3000)
TIMED_MARK = "chip.timed_from_here"
_BUCKETS = const(5000)  # 1 us histogram buckets; longer go to the last one (and the maxima)
_service_hist = array("H", bytes(2 * _BUCKETS))
_iteration_hist = array("H", bytes(2 * _BUCKETS))
_s = array("i", bytes(4 * 20))
_PHASE = const(0)  # 0 booting, 1 allocation, 2 catching up, 3 timing
_CALLS = const(1)
_SERVICE_MAX = const(2)
_ALLOC_SUM = const(3)
_ALLOC_CALLS = const(4)
_START = const(5)
_DURATION = const(6)
_COLLECTIONS = const(8)
_GC_ITERATION_MAX = const(9)
_LAST_START = const(10)
_CHECKED_ALLOC = const(11)
_ITERATIONS = const(12)
_SKIP_NEXT = const(13)
_ITERATION_MAX = const(14)
_ALLOC_DONE = const(15)
_SETTLED = const(16)
_CAUGHT_UP = const(17)
_TRACE = const(18)

# The original host's SETUP (drive 30 %, hold 10 %), so the host's cycling SETRPM turns the joint.
_SETUP = bytearray((SETUP, 30, 10, 0, 0))
# The trace run: the original detector sampling (sensitivity 6) with `trace on` typed at the console.
_STALLGUARD = bytearray((ENABLESTALLGUARD, 6))
_service = core.JointController.service
_poll = debug.DebugConsole.poll
_ticks_us = time.ticks_us
_diff = time.ticks_diff
_mem_alloc = gc.mem_alloc


class Done(Exception):
    pass


def _allocation_phase(self, s):
    if s[_SETTLED] < SETTLE_CALLS:  # the one-off work of the enable (its log lines) is not steady state
        s[_SETTLED] += 1
        return _service(self)
    a0 = _mem_alloc()
    _service(self)
    a1 = _mem_alloc()
    if a1 >= a0:
        s[_ALLOC_SUM] += a1 - a0
        s[_ALLOC_CALLS] += 1
    s[_ALLOC_DONE] += 1
    if s[_ALLOC_DONE] >= ALLOC_CALLS:
        s[_PHASE] = 2


def _catching_up(self, s):
    # The allocation phase's iterations took ~18 ms each: the host's commands queued meanwhile
    # and the overdue detector ticks are its doing, not the loop's steady state.
    _service(self)
    s[_CAUGHT_UP] += 1
    if s[_CAUGHT_UP] >= CATCH_UP_CALLS:
        s[_PHASE] = 3
        if s[_TRACE]:
            print(TIMED_MARK)  # on the console between the trace lines: those after it are timed
        s[_CHECKED_ALLOC] = _mem_alloc()
        s[_START] = s[_LAST_START] = _ticks_us()
        s[_SKIP_NEXT] = 1


def _timed_service(self):
    s = _s
    phase = s[_PHASE]
    if phase == 0:
        return _service(self)
    if phase == 1:
        return _allocation_phase(self, s)
    if phase == 2:
        return _catching_up(self, s)
    t0 = _ticks_us()
    iteration = _diff(t0, s[_LAST_START])
    s[_LAST_START] = t0
    _service(self)
    t1 = _ticks_us()
    dt = _diff(t1, t0)
    s[_CALLS] += 1
    if dt > s[_SERVICE_MAX]:
        s[_SERVICE_MAX] = dt
    _service_hist[dt if dt < _BUCKETS else _BUCKETS - 1] += 1
    if s[_SKIP_NEXT]:
        s[_SKIP_NEXT] = 0
    else:
        s[_ITERATIONS] += 1
        _iteration_hist[iteration if iteration < _BUCKETS else _BUCKETS - 1] += 1
        if iteration > s[_ITERATION_MAX]:
            s[_ITERATION_MAX] = iteration
        if iteration > STALL_US:
            allocated = _mem_alloc()
            if allocated < s[_CHECKED_ALLOC]:
                s[_COLLECTIONS] += 1
                if iteration > s[_GC_ITERATION_MAX]:
                    s[_GC_ITERATION_MAX] = iteration
            s[_CHECKED_ALLOC] = allocated
            s[_SKIP_NEXT] = 1
    if _diff(t1, s[_START]) >= s[_DURATION]:
        raise Done()


def _first_poll(self):
    s = _s
    if s[_PHASE] == 0:
        # The joint is built, on the bus, its console up: enable it as a host would, start measuring.
        self.core.on_frame(_SETUP, len(_SETUP))
        if s[_TRACE]:
            self.core.set_stall_detector("original")
            self.core.on_frame(_STALLGUARD, len(_STALLGUARD))
            self.execute("trace", ["on"])
        gc.collect()
        s[_PHASE] = 1
    return _poll(self)


def _percentile(hist, count, fraction):
    want = fraction * count
    seen = 0
    for us in range(_BUCKETS):
        seen += hist[us]
        if seen >= want:
            return us
    return _BUCKETS


def run(duration_ms=5000, trace=False):
    """Run the joint's main loop for `duration_ms` (emulated) and print the figures. `trace`: with
    the original detector sampling and its trace on the console."""
    s = _s
    s[_DURATION] = duration_ms * 1000
    s[_TRACE] = 1 if trace else 0
    core.JointController.service = _timed_service
    debug.DebugConsole.poll = _first_poll
    try:
        app.run()
    except Done:
        pass
    finally:
        core.JointController.service = _service
        debug.DebugConsole.poll = _poll
    elapsed = _diff(_ticks_us(), s[_START])
    if _mem_alloc() < s[_CHECKED_ALLOC]:
        s[_COLLECTIONS] += 1  # one that never stalled the loop past STALL_US
    median_iteration = _percentile(_iteration_hist, s[_ITERATIONS], 0.5)
    gc_pause = max(0, s[_GC_ITERATION_MAX] - median_iteration) if s[_GC_ITERATION_MAX] else 0
    print("chip.service_us_median", _percentile(_service_hist, s[_CALLS], 0.5))
    print("chip.service_us_p99", _percentile(_service_hist, s[_CALLS], 0.99))
    print("chip.service_us_max", s[_SERVICE_MAX])
    print("chip.alloc_bytes_per_service", s[_ALLOC_SUM] / max(1, s[_ALLOC_CALLS]))
    print("chip.gc_pause_ms_max", gc_pause / 1000)
    print("chip.gc_collections", s[_COLLECTIONS])
    print("chip.loop_iteration_us_median", median_iteration)
    print("chip.loop_iteration_us_max", s[_ITERATION_MAX])
    print("chip.loop_hz", s[_CALLS] * 1e6 / elapsed)
    print("chip.loop_seconds", elapsed / 1e6)
