"""Boot the joint on CircuitPython and run its main loop: the core, the configuration and the
debug console of app.py, the motor on hardware.py's objects, the joint bus through `i2ctarget`
polled by the loop (cp_target.py).

The loop serves the bus before and after the core's iteration and while it waits for the next
millisecond tick (supervisor.ticks_ms: a small int, where time.monotonic_ns allocates a long int
every call), so the host waits at most about one core iteration for a reply. The garbage
collector is the loop's (CollectionPlan): the heap is collected once the bus has been quiet for a
while (hosts poll in bursts) after a period's allocation, at once after 5/4 of that. Automatic
collection stays on as the safety net (with no threshold set it runs only when an allocation finds
no room; gc.disable made that a MemoryError, which ended the loop in a fast move once the loop
allocated less at rest than moving).
CircuitPython lacks what MicroPython gives the core (native and viper code, time.ticks_*): the
same core runs as bytecode on cpy/clock.py's small-int clock (docs/circuitpython.md has the costs).
"""

from .. import app as mp_app
# Kept for the joint's life here, unlike on MicroPython: with startup.py forgotten after boot,
# every collection of this loop took 17 ms instead of 9 (bench/chip_cp.py; cause not found).
from .. import startup
from ..links.cp_target import CircuitPythonTargetAdapter
from ..console.debug import DebugConsole
from ..config.settings import CONFIG_FILE
from .clock import TICKS_PERIOD, TickClock
from .hardware import EncoderBus, StepMachine, no_bus

SLOW_EVERY_MASK = 3  # the console: every 4th iteration
# A collection (about 10 ms) waits for this many millisecond ticks without a request (at least
# 1 ms: a host's transactions come back to back) ...
QUIET_MS = 2
CALIBRATE = 64  # iterations whose allocation sets how often the loop collects
# ... once a period has allocated this many eighths of the heap free after a collection, at once
# at 5/4 of that (the heap 78% full). Every collection delays the next transaction of a host
# cycling at 100 Hz by a few ms: a period of 1/4 of the heap (7 collections/s, bench/chip_cp.py)
# made that every 100th transaction (SCL held p99 5.5 ms), 5/8 (~1.6/s) makes it rarer.
PERIOD_EIGHTHS = 5
# What a served request allocates, in i2ctarget and links/cp_target.py: a read 16 bytes (the
# request), a write the request, its bytes and 2-4 register reads of 32 bytes each. Measured: a
# moving joint under a host cycling at 100 Hz (600 requests/s) allocated 139 bytes an iteration
# at 440 Hz, about 1 idle (bench/chip_cp.py): 100 bytes a request.
REQUEST_BYTES = 100
SERVED_MASK = 0x3FFFFFFF  # CircuitPythonTargetAdapter.served wraps so
TICKS_MASK = TICKS_PERIOD - 1
PROTOCOL_V2 = 2  # protocol_v2.PROTOCOL_V2, without loading the v2 spec


def build_motor(cfg, clock):
    if cfg.motor.get("backend") == "pico":
        from ..pico.motor import PicoStepper
        from .hardware import build_stepper
        return build_stepper(PicoStepper, cfg.motor, clock)
    raise ValueError("motor backend %r cannot run on a board" % cfg.motor.get("backend"))


def boot(config_path=CONFIG_FILE):
    """startup.boot on CircuitPython: the controller built and its boot task run to its end."""
    import time
    import supervisor

    from ..core import loop, tasks
    from .fixed import store_q

    loop.store_q = tasks.store_q = store_q  # the core's reply-cache packing, without allocating
    clock = TickClock(supervisor.ticks_ms)
    core, cfg, log = startup.build(None, config_path, clock,
                                   motor_builder=lambda cfg: build_motor(cfg, clock))
    while not core.ready:
        core.service()
        time.sleep(0.001)
    startup.drop_boot_only()
    return core, cfg, log


def join_bus(core, cfg, log):
    """The legacy map on an i2ctarget.I2CTarget at the configured address and pins."""
    if cfg.address is None:
        log.error("no valid I2C address configured: not joining the bus")
        return None
    i2c = cfg.i2c
    try:
        import i2ctarget
        from .hardware import TargetFifo, gpio
        target = i2ctarget.I2CTarget(gpio(i2c.scl), gpio(i2c.sda), (cfg.address,))
        fifo = TargetFifo(i2c.sda)
    except (ValueError, OSError, RuntimeError, ImportError) as exc:
        log.error("cannot join the bus as I2C target 0x%02x (SDA %d, SCL %d): %r"
                  % (cfg.address, i2c.sda, i2c.scl, exc))
        return None
    return CircuitPythonTargetAdapter(core, target, fifo)


class CollectionPlan:
    """When the loop collects the heap: once a period has allocated PERIOD_EIGHTHS of the heap
    free after a collection, at a quiet moment of the bus, at once at 5/4 of that. A period's
    allocation is counted, not read (gc.mem_free walks the whole heap, about as long as a core
    iteration): its iterations at the bytes each allocates, measured over the first CALIBRATE
    (those allocate more than later ones: each path's first calls), and the bus's requests served
    at REQUEST_BYTES each, so that a host starting to poll a joint booted idle (about 1 byte an
    iteration) is counted as it comes instead of leaving the collection to a full heap."""

    def __init__(self, gc, link, log, stride):
        self._gc = gc
        self._link = link  # its `served` counts the requests (None: no bus)
        self._stride = stride  # iterations a call of due() counts (not called every iteration:
        # a method call and its attribute loads take tens of us on the chip)
        self._log = log
        self._free = gc.mem_free()  # before calibrating
        self.budget = 0  # bytes a period allocates: 0 while calibrating
        self.per_iteration = 0
        self._iterations = 0
        self._served = 0

    def due(self, quiet):
        """Count `stride` iterations; True: collect now (`quiet`: the bus has been quiet long
        enough)."""
        self._iterations += self._stride
        link = self._link
        served = link.served if link is not None else 0
        if not self.budget:
            if self._iterations >= CALIBRATE:
                self._calibrate()
            return False
        used = self._iterations * self.per_iteration + ((served - self._served) & SERVED_MASK) * REQUEST_BYTES
        if used < self.budget or (used < self.budget + (self.budget >> 2) and not quiet):
            return False
        self._iterations = 0
        self._served = served
        return True

    def _calibrate(self):
        gc = self._gc
        self.per_iteration = (self._free - gc.mem_free()) // self._iterations + 1
        gc.collect()
        self.budget = gc.mem_free() * PERIOD_EIGHTHS // 8
        self._log.info("collecting every %d bytes allocated (%d bytes per iteration, %d per request)"
                       % (self.budget, self.per_iteration, REQUEST_BYTES))
        self._iterations = self.budget // self.per_iteration  # collect at the next quiet moment


class SerialConsole:
    """The USB serial console for DebugConsole: `read(buf)` takes only bytes already there,
    `write(line)` prints a line (a str, or the trace's bytes)."""

    def __init__(self):
        import sys
        import supervisor

        self._runtime = supervisor.runtime
        self._stdin = sys.stdin
        self._stdout = sys.stdout

    def read(self, buf):
        n = 0
        while n < len(buf) and self._runtime.serial_bytes_available:
            buf[n] = ord(self._stdin.read(1))
            n += 1
        return n

    def write(self, line):
        self._stdout.write(line if isinstance(line, str) else str(bytes(line), "ascii"))
        self._stdout.write("\n")


class LoopMeter:
    """Figures of the running loop for the benchmark: iteration times (us, the work before the
    wait) of every STRIDE-th iteration, `every` of them a report, collections and their
    times; `report()` prints them as `name value` lines and starts over. Its microsecond clock is
    time.monotonic_ns (the joint's clock counts whole milliseconds), a long int a read: the bytes
    a read allocates, measured here, are taken off the allocation figure, which is then the
    joint's own. Timing every iteration made the meter's garbage as much as the joint's (twice
    the collections: 3.5/s, the loop 440 Hz). STRIDE is prime to the loop's 4-iteration turn,
    so the timed iterations take each of its jobs in turn."""

    STRIDE = 5

    def __init__(self, every, gc):
        from array import array
        import time

        self.every = every
        self.times = array("H", bytes(2 * every))
        self.count = 0  # iterations timed, every STRIDE-th
        self.collections = 0
        self.collect_us = 0
        self.collect_max_us = 0
        self.allocated = 0  # bytes allocated since the last report, less the clock's
        self.base = 0  # gc.mem_alloc() after the last collection or report
        self._ns = time.monotonic_ns
        self.reads = 0
        gc.collect()
        before = gc.mem_alloc()
        for _ in range(8):
            self.now_us()
        self.read_bytes = (gc.mem_alloc() - before) // 8
        self.started = self.now_us()
        self.reads = 0  # those before run() sets `base`

    def now_us(self):
        self.reads += 1
        return self._ns() // 1000

    def add(self, spent):
        self.times[self.count] = spent if spent < 65535 else 65535
        self.count += 1

    def collect(self, gc):
        self.allocated += gc.mem_alloc() - self.base
        start = self._ns()  # outside the window: not counted in `reads`
        gc.collect()
        spent = (self._ns() - start) // 1000
        self.base = gc.mem_alloc()
        self.collections += 1
        self.collect_us += spent
        if spent > self.collect_max_us:
            self.collect_max_us = spent

    def report(self, gc):
        now = self.now_us()
        seconds = (now - self.started) / 1e6
        self.started = now
        times = sorted(self.times)
        n = len(times)
        self.allocated += gc.mem_alloc() - self.base - self.reads * self.read_bytes
        iterations = n * self.STRIDE
        print("cp.loop.alloc_bytes_per_iteration %d" % (self.allocated // iterations))
        print("cp.loop.hz %.1f" % (iterations / seconds))
        print("cp.loop.iteration_us.median %d" % times[n // 2])
        print("cp.loop.iteration_us.p99 %d" % times[(n * 99) // 100])
        print("cp.loop.iteration_us.max %d" % times[-1])
        print("cp.gc.collections_per_s %.2f" % (self.collections / seconds))
        print("cp.gc.collect_us.mean %d" % (self.collect_us // max(1, self.collections)))
        print("cp.gc.collect_us.max %d" % self.collect_max_us)
        print("cp.heap.free %d" % gc.mem_free())
        self.count = self.collections = self.collect_us = self.collect_max_us = self.allocated = 0
        self.reads = 0
        self.base = gc.mem_alloc()  # after the report's own strings


def run(config_path=CONFIG_FILE, meter_every=0):
    """The joint: boot, join the bus, loop until Ctrl-C. `meter_every` > 0: print the loop's
    figures (LoopMeter) every that many timed iterations, for bench/chip_cp.py."""
    import gc
    import supervisor

    core, cfg, log = boot(config_path)
    link = join_bus(core, cfg, log)
    console = SerialConsole()
    log.set_writer(console.write)
    debug = DebugConsole(core, console.read, console.write)
    ticks_ms = supervisor.ticks_ms
    meter = LoopMeter(meter_every, gc) if meter_every > 0 else None
    gc.collect()
    if meter is not None:
        meter.base = gc.mem_alloc()
    log.info("CircuitPython joint: %d bytes of heap free" % gc.mem_free())
    serve = link.poll if link is not None else no_bus
    # The bus served mid-iteration too: as the motor's update starts (its look at the step
    # FIFO), after the encoder's read and after a step burst is queued.
    EncoderBus.serve = StepMachine.serve = serve
    turn = sample = 0
    quiet_since = ticks_ms()
    plan = CollectionPlan(gc, link, log, SLOW_EVERY_MASK + 1)  # asked every 4th iteration
    try:
        while True:
            tick = ticks_ms()
            if meter is not None:  # one iteration in LoopMeter.STRIDE timed, in turn with `turn`'s
                sample = sample - 1 if sample else LoopMeter.STRIDE - 1
                start = meter.now_us() if sample == 0 else -1
            while serve():
                quiet_since = tick
            core.service()
            while serve():
                quiet_since = tick
            if core.protocol_request:
                _refuse_protocol(core, log)
            turn = (turn + 1) & SLOW_EVERY_MASK
            if turn == 0:
                try:
                    debug.poll()
                except Exception as exc:  # the console must never end the control loop
                    log.error("debug console: %r" % (exc,))
            elif turn == 2 and plan.due(((tick - quiet_since) & TICKS_MASK) >= QUIET_MS):
                if meter is None:
                    gc.collect()
                else:
                    meter.collect(gc)
            if meter is not None and start >= 0:
                meter.add(meter.now_us() - start)
                if meter.count == meter.every:
                    meter.report(gc)
            # The next iteration starts at the next millisecond tick; the bus is served meanwhile.
            while ticks_ms() == tick:
                if serve():
                    quiet_since = tick
    except KeyboardInterrupt:
        mp_app.shut_down(core, link, log)
        raise


def _refuse_protocol(core, log):
    """The host asked for another protocol (PROTOCOL register): v2 needs a memory-mode I2C
    target, which CircuitPython's i2ctarget does not have; the joint keeps the legacy map and
    the host, finding no v2 state block, stays on legacy."""
    if core.protocol_request == PROTOCOL_V2:
        log.warn("protocol v2 needs a memory-mode I2C target, which CircuitPython lacks: "
                 "serving the legacy map")
    core.protocol_request = 0
