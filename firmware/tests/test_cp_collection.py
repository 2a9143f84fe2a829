"""When the CircuitPython joint's loop collects the heap (cpy/app.py CollectionPlan): before the
heap fills, at the bus's quiet moments, also once a host starts polling a joint that booted idle.

Plain functions and bare asserts: this module runs under CPython (pytest) and the MicroPython unix
port (mprun.py).
"""

from joint.cpy.app import CALIBRATE, CollectionPlan
from joint.console.log import Logger


class FakeHeap:
    """gc's mem_free and collect over a heap of `size` bytes, `used` of them garbage or live."""

    def __init__(self, size, live):
        self.size = size
        self.live = live
        self.used = live
        self.collections = 0

    def mem_free(self):
        return self.size - self.used

    def collect(self):
        self.used = self.live
        self.collections += 1

    def allocate(self, n):
        assert self.used + n <= self.size, "the heap filled: CircuitPython's own collector ran"
        self.used += n


class FakeLink:
    served = 0


def _calibrated(heap, link, per_iteration):
    said = []
    plan = CollectionPlan(heap, link, Logger("J1", write=said.append), 1)
    for _ in range(CALIBRATE):
        heap.allocate(per_iteration)
        assert not plan.due(True)
    assert "collecting every %d bytes" % plan.budget in said[-1]
    return plan


def _run(plan, heap, link, iterations, per_iteration, requests_per_iteration, request_bytes, quiet):
    """`iterations` loop iterations; returns the heap's largest use (bytes)."""
    peak = 0
    for _ in range(iterations):
        heap.allocate(per_iteration + requests_per_iteration * request_bytes)
        link.served += requests_per_iteration
        peak = max(peak, heap.used)
        if plan.due(quiet):
            heap.collect()
    return peak


def test_a_host_polling_a_joint_booted_idle_is_collected_for_before_the_heap_fills():
    heap, link = FakeHeap(150_000, 10_000), FakeLink()
    plan = _calibrated(heap, link, 1)  # no host yet: about a byte an iteration
    # A host polling: a request an iteration, writes (176 bytes) and reads (16) in turn.
    peak = _run(plan, heap, link, 20_000, 1, 1, 96, True)
    assert heap.collections >= 20_000 * 96 // 140_000
    assert peak - heap.live <= (heap.size - heap.live) * 13 // 16  # 5/4 of 5/8, and a request


def test_the_collection_waits_for_a_quiet_bus_until_5_4_of_its_period():
    heap, link = FakeHeap(150_000, 10_000), FakeLink()
    plan = _calibrated(heap, link, 100)
    _run(plan, heap, link, 1, 100, 0, 0, True)
    assert heap.collections == 2  # calibrating, then at the first quiet moment after it
    period = plan.budget // plan.per_iteration  # iterations, the last below the budget
    _run(plan, heap, link, period + 1, 100, 0, 0, False)
    assert heap.collections == 2  # a period's allocation, the bus busy: not yet
    _run(plan, heap, link, period // 4 + 1, 100, 0, 0, False)
    assert heap.collections == 3  # 5/4 of the period: at once
    _run(plan, heap, link, period + 1, 100, 0, 0, True)
    assert heap.collections == 4  # a period, the bus quiet
