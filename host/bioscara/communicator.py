"""The fixed-rate communicator: the arm's read/write cycle at a configured frequency.

Like the IgH EtherCAT master's cyclic task: `start()` runs the cycle in a loop thread (SCHED_FIFO
when the process may use it), `stop()` ends it, `restart()` does both. Time is the bus clock, so on
the simulated bus the loop runs in virtual time: cycles are exactly one period apart unless the
cycle itself (its wire time) takes longer, which is counted as an overrun.

Each cycle publishes a `Snapshot` of named values (position, velocity, flags, home per joint) to
subscribers through bounded queues: a slow subscriber loses its oldest snapshots (counted in
`Subscription.dropped`), it never blocks the loop.

Without a thread, `run_until()` / `run_for()` cycle in the calling thread, which keeps scenarios on
the simulated bus deterministic; with the thread running they wait for the loop instead.
"""

from __future__ import annotations

import logging
import math
import os
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass, field

from .arm import Arm, Lifecycle
from .errors import BioscaraError, InvalidArgumentError
from .joint import WaitTimeoutError

log = logging.getLogger("bioscara.communicator")


@dataclass(frozen=True)
class JointSample:
    position: float
    velocity: float
    flags: int
    home: float


@dataclass(frozen=True)
class Snapshot:
    cycle: int
    time: float  # bus clock, s
    joints: dict[str, JointSample]
    fault: str | None = None

    def values(self) -> dict[str, float]:
        """Flat named values: "j1/position", "j1/velocity", "j1/flags", "j1/home", ..."""
        out: dict[str, float] = {}
        for name, sample in self.joints.items():
            out[f"{name}/position"] = sample.position
            out[f"{name}/velocity"] = sample.velocity
            out[f"{name}/flags"] = sample.flags
            out[f"{name}/home"] = sample.home
        return out


class Subscription:
    """Snapshots delivered by the loop; keeps the newest `maxlen`."""

    def __init__(self, maxlen: int) -> None:
        self._queue: deque[Snapshot] = deque(maxlen=maxlen)
        self._ready = threading.Condition()
        self.dropped = 0

    def _put(self, snapshot: Snapshot) -> None:
        with self._ready:
            if len(self._queue) == self._queue.maxlen:
                self.dropped += 1
            self._queue.append(snapshot)
            self._ready.notify_all()

    def get(self, timeout: float | None = None) -> Snapshot | None:
        """The oldest undelivered snapshot, waiting up to `timeout` s (None if none arrived)."""
        with self._ready:
            if not self._queue and not self._ready.wait_for(lambda: bool(self._queue), timeout):
                return None
            return self._queue.popleft()

    def drain(self) -> list[Snapshot]:
        with self._ready:
            items = list(self._queue)
            self._queue.clear()
            return items


@dataclass
class TimingStats:
    """Cycle timing on the bus clock, seconds. Jitter is the standard deviation of the period."""

    cycles: int = 0
    overruns: int = 0
    errors: int = 0
    period_mean: float = 0.0
    period_min: float = math.inf
    period_max: float = 0.0
    duration_mean: float = 0.0
    duration_max: float = 0.0
    _period_m2: float = field(default=0.0, repr=False)

    @property
    def jitter(self) -> float:
        periods = self.cycles - 1
        return math.sqrt(self._period_m2 / periods) if periods > 1 else 0.0

    @property
    def rate(self) -> float:
        return 1.0 / self.period_mean if self.period_mean > 0 else 0.0

    def add(self, period: float | None, duration: float, overrun: bool) -> None:
        self.cycles += 1
        self.overruns += overrun
        self.duration_mean += (duration - self.duration_mean) / self.cycles
        self.duration_max = max(self.duration_max, duration)
        if period is not None:
            n = self.cycles - 1
            delta = period - self.period_mean
            self.period_mean += delta / n
            self._period_m2 += delta * (period - self.period_mean)
            self.period_min = min(self.period_min, period)
            self.period_max = max(self.period_max, period)


class Communicator:
    def __init__(self, arm: Arm, frequency: float = 100.0, *, realtime_priority: int | None = 50) -> None:
        if not 0 < frequency <= 10_000:
            raise InvalidArgumentError(f"the cycle rate must be in (0, 10000] Hz, got {frequency:g}")
        self.arm = arm
        self.bus = arm.bus
        self.frequency = frequency
        self.period = 1.0 / frequency
        self.realtime_priority = realtime_priority
        self.stats = TimingStats()
        self.last: Snapshot | None = None
        self.scheduling = "not started"
        self.thread_error: Exception | None = None
        self._subscriptions: list[Subscription] = []
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._cycled = threading.Condition()
        self._last_start: float | None = None
        self._next: float | None = None

    # ---- subscribers and health ----

    def subscribe(self, maxlen: int = 1000) -> Subscription:
        subscription = Subscription(maxlen)
        self._subscriptions.append(subscription)
        return subscription

    def unsubscribe(self, subscription: Subscription) -> None:
        self._subscriptions.remove(subscription)

    def link_health(self) -> dict[str, dict[str, object]]:
        """Per joint, its bus.LinkStats: transactions, failed attempts, transactions lost after
        retries (comm_errors), bits, last error."""
        return {name: asdict(self.bus.stats.link(aj.config.address)) for name, aj in self.arm.joints.items()}

    # ---- the cycle ----

    def cycle(self) -> Snapshot:
        """One read/write cycle (write only while the arm is active); publishes its snapshot."""
        start = self.bus.monotonic()
        fault = None
        try:
            if self.arm.lifecycle in (Lifecycle.INACTIVE, Lifecycle.ACTIVE):
                self.arm.cycle()
        except BioscaraError as exc:
            fault = str(exc)
            self.stats.errors += 1
        end = self.bus.monotonic()
        period = start - self._last_start if self._last_start is not None else None
        self._last_start = start
        self.stats.add(period, end - start, end - start > self.period)
        snapshot = Snapshot(self.stats.cycles, start, {
            name: JointSample(aj.state.position, aj.state.velocity, aj.joint.flags, aj.state.home)
            for name, aj in self.arm.joints.items()}, fault)
        self.last = snapshot
        for subscription in list(self._subscriptions):
            subscription._put(snapshot)
        with self._cycled:
            self._cycled.notify_all()
        return snapshot

    def _wait_next(self) -> None:
        now = self.bus.monotonic()
        self._next = now if self._next is None else self._next + self.period
        if self._next < now - self.period:
            self._next = now  # fell behind by more than a period: do not burst to catch up
        if self._next > now:
            self.bus.sleep(self._next - now)

    # ---- in the calling thread ----

    def run_for(self, seconds: float, *, stop_on_fault: bool = True) -> None:
        self.run_until(lambda: False, seconds, raise_on_timeout=False, stop_on_fault=stop_on_fault)

    def run_until(self, predicate: Callable[[], bool], timeout: float, *, raise_on_timeout: bool = True,
                  stop_on_fault: bool = True) -> None:
        """Cycle until `predicate()` holds (checked after each cycle) or `timeout` s pass on the bus clock.

        A new arm fault (the cycle failed, the arm disabled its joints) ends the wait by raising that
        error, unless `stop_on_fault` is False (monitoring a bus with a missing joint, say).
        """
        deadline = self.bus.monotonic() + timeout
        fault = self.arm.fault

        def finished() -> bool:
            if stop_on_fault and self.arm.fault is not None and self.arm.fault is not fault:
                raise self.arm.fault
            return predicate()
        if self.running:
            with self._cycled:
                while not finished():
                    remaining = deadline - self.bus.monotonic()
                    if remaining <= 0 or not self.running:
                        break
                    self._cycled.wait(min(remaining, 0.1) if self.bus.scheme != "sim" else 0.01)
            done = finished()
        else:
            done = False
            while True:
                self._wait_next()
                self.cycle()
                if finished():
                    done = True
                    break
                if self.bus.monotonic() >= deadline:
                    break
        if not done and raise_on_timeout:
            raise WaitTimeoutError(f"not done after {timeout:g} s")

    # ---- the loop thread ----

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> None:
        if self.running:
            return
        self._stop.clear()
        self._next = None
        self._last_start = None  # the pause is not a period
        self._thread = threading.Thread(target=self._loop, name="bioscara-communicator", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 5.0) -> None:
        if self._thread is None:
            return
        self._stop.set()
        self._thread.join(timeout)
        if self._thread.is_alive():
            raise BioscaraError(f"communicator thread did not stop within {timeout:g} s")
        self._thread = None

    def restart(self) -> None:
        self.stop()
        self.start()

    def reset_stats(self) -> None:
        """Count the timing from now (e.g. from `start`, not from cycles run by hand before it)."""
        self.stats = TimingStats()
        self._last_start = None

    def _loop(self) -> None:
        self._set_scheduling()
        try:
            while not self._stop.is_set():
                self._wait_next()
                self.cycle()
        except Exception as exc:  # a bug or an unexpected error: say so instead of dying silently
            self.thread_error = exc
            log.exception("communicator loop stopped: %s", exc)

    def _set_scheduling(self) -> None:
        if self.realtime_priority is None or not hasattr(os, "sched_setscheduler"):
            self.scheduling = "normal"
            return
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self.realtime_priority))
            self.scheduling = f"SCHED_FIFO priority {self.realtime_priority}"
        except PermissionError:
            self.scheduling = "normal"
            log.warning("real-time scheduling (SCHED_FIFO) not permitted: running at normal priority; "
                        "grant it with `sudo setcap cap_sys_nice+ep $(readlink -f $(which python3))` "
                        "or an rtprio entry in /etc/security/limits.conf")
        except OSError as exc:
            self.scheduling = "normal"
            log.warning("real-time scheduling unavailable (%s): running at normal priority", exc)
