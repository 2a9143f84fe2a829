"""`python bench/chip_profile.py [ms]`: where the main loop's time and the heap go, on the emulated
Pico (the deployed joint as bench/chip_bench.py runs it, the host cycling). Each method in
TARGETS is wrapped to add up its calls and inclusive microseconds (the wrappers cost a few
microseconds each, charged to the callers: compare rows, not sums). The heap part imports the
firmware's modules one by one after a soft reset and prints what each kept. A tool for finding
costs, not a figure: the figures are `make bench-chip`'s.
"""

from __future__ import annotations

import pathlib
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "bench")]

from chip.board import EmulatedPico  # noqa: E402
from chip.paths import missing  # noqa: E402
import chip_bench  # noqa: E402

# (module, class, method, arity after self)
TARGETS = [
    ("joint.core.controller", "JointController", "service", 0),
    ("joint.core.controller", "JointController", "_apply_next", 0),
    ("joint.core.controller", "JointController", "_step_task", 1),
    ("joint.core.controller", "JointController", "_check_stall", 0),
    ("joint.core.controller", "JointController", "_check_tracking", 0),
    ("joint.core.controller", "JointController", "_check_deadman", 0),
    ("joint.core.controller", "JointController", "_host_angle", 0),
    ("joint.core.controller", "JointController", "_encoder_usteps", 0),
    ("joint.core.controller", "JointController", "_motion_active", 0),
    ("joint.pico.motor", "PicoStepper", "update", 0),
    ("joint.pico.motor", "PicoStepper", "encoder_rpm", 0),
    ("joint.pico.motor", "PicoStepper", "driver_rpm", 0),
    ("joint.pico.motor", "PicoStepper", "pid_error", 0),
    ("joint.pico.motor", "PicoStepper", "angle_moved", 0),
    ("joint.pico.motor", "PicoStepper", "field_position", 0),
    ("joint.pico.motor", "PicoStepper", "position_reached", 0),
    ("joint.pico.as5600", "AS5600", "sample", 2),
    ("joint.detect.tracking", "TrackingDetector", "update", 2),
    ("joint.links.memmap_v2", "ProtocolSwitch", "service", 0),
    ("joint.console.debug", "DebugConsole", "poll", 0),
]

PROFILER = '''
import gc, time
from array import array
_t = time.ticks_us
_d = time.ticks_diff
CALLS = array("i", [0] * {n})
US = array("i", [0] * {n})

def wrap(cls, name, arity, i):
    f = getattr(cls, name)
    if arity == 0:
        def w(self):
            t0 = _t(); r = f(self); US[i] += _d(_t(), t0); CALLS[i] += 1; return r
    elif arity == 1:
        def w(self, a):
            t0 = _t(); r = f(self, a); US[i] += _d(_t(), t0); CALLS[i] += 1; return r
    elif arity == 2:
        def w(self, a, b):
            t0 = _t(); r = f(self, a, b); US[i] += _d(_t(), t0); CALLS[i] += 1; return r
    else:
        def w(self, a, b, c):
            t0 = _t(); r = f(self, a, b, c); US[i] += _d(_t(), t0); CALLS[i] += 1; return r
    setattr(cls, name, w)

def _empty(self):
    return None

class _Cal:
    pass
'''

RUN = '''
import gc, time, sys
from joint import app
from joint.core import controller as core
from joint.console import debug
from joint.spec import protocol as P
{imports}
exec(open("/prof.py").read())
names = {names!r}
for i, (mod, cls, meth, ar) in enumerate({targets!r}):
    m = sys.modules.get(mod)
    if m is not None and hasattr(getattr(m, cls, None), meth):
        wrap(getattr(m, cls), meth, ar, i)
_Cal.m = _empty
wrap(_Cal, "m", 0, len(names))
c = _Cal()
for _ in range(200):
    c.m()
_SETUP = bytearray((P.SETUP, 30, 10, 0, 0))
state = [0, 0]
_poll = debug.DebugConsole.poll
class Done(BaseException):
    pass
def first_poll(self):
    if state[0] == 0:
        self.core.on_frame(_SETUP, len(_SETUP))
        gc.collect()
        for k in range(len(CALLS) - 1):
            CALLS[k] = 0
            US[k] = 0
        state[0] = 1
        state[1] = time.ticks_ms()
    elif time.ticks_diff(time.ticks_ms(), state[1]) > {ms}:
        raise Done()
    return _poll(self)
debug.DebugConsole.poll = first_poll
try:
    app.run()
except Done:
    pass
n = CALLS[0]
print("overhead_us_per_wrapped_call", US[len(names)] / CALLS[len(names)])
for i, name in enumerate(names):
    if CALLS[i]:
        print("%-40s calls %6d  per_service %6.3f  us_each %8.1f  us_per_service %8.1f" % (
            name, CALLS[i], CALLS[i] / n, US[i] / CALLS[i], US[i] / n))
'''

HEAP = '''
import gc, sys
gc.collect()
base = gc.mem_free()
print("heap_free_kb_at_start", base / 1024)
last = base
for m in {modules!r}:
    __import__(m)
    gc.collect()
    free = gc.mem_free()
    print("%-24s %6d bytes" % (m, last - free))
    last = free
from joint import app, startup
import machine
core, cfg, log = startup.boot(machine)
gc.collect(); free = gc.mem_free()
print("%-24s %6d bytes" % ("startup.boot()", last - free)); last = free
switch = app.join_bus(machine, core, cfg, log)
from joint.console.debug import DebugConsole, UsbStdio
stdio = UsbStdio()
d = DebugConsole(core, stdio.read, stdio.write)
gc.collect(); free = gc.mem_free()
print("%-24s %6d bytes" % ("boot+bus+console", last - free)); last = free
print("heap_free_kb_after_boot", free / 1024)
import micropython
micropython.mem_info()
micropython.qstr_info()
'''

MODULES = ["joint.micro", "joint.motion.fixed", "joint.spec.protocol_v2", "joint.spec.protocol", "joint.core.irq",
           "joint.detect.stall",
           "joint.detect.tracking", "joint.detect.homing", "joint.core.supervise", "joint.core.handlers", "joint.core.tasks",
           "joint.core.loop", "joint.spec.version", "joint.spec.regtable", "joint.core.controller", "joint.config.settings", "joint.config.schema", "joint.core.clock", "joint.console.log",
           "joint.motion.hal", "joint.motion.tickramp", "joint.motion.velocity", "joint.pico.tmc2209", "joint.pico.as5600",
           "joint.pico.stepgen", "joint.pico.motor", "joint.links.i2c_target",
           "joint.links.memmap_v2", "joint.console.debug", "joint.app", "joint.startup"]


# The main loop's parts timed one after another, on a joint turning at 30 rpm, no host traffic
# (no IRQ in the figures): mean microseconds per iteration of each part.
PARTS = '''
import gc, time, machine
from joint import app, startup
from joint.core import irq
from joint.spec import protocol as P
from joint.console.debug import DebugConsole, UsbStdio
from joint.motion.fixed import store_q
core, cfg, log = startup.boot(machine)
switch = app.join_bus(machine, core, cfg, log)
stdio = UsbStdio()
console = DebugConsole(core, stdio.read, stdio.write)
core.on_frame(bytearray((P.SETUP, 30, 10, 0, 0)), 5)
import struct
f = bytearray(5); f[0] = P.SETRPM; struct.pack_into("<f", f, 1, {rpm})
core.on_frame(f, 5)
for _ in range(500):
    core.service(); time.sleep_ms(1)
t = time.ticks_us
d = time.ticks_diff
hal = core.hal
names = ("service", "hal.update", "apply/task/pos", "stall+track", "deadman", "angle_cache",
         "switch.service", "console.poll", "steps.poll", "enc.sample", "vel.update", "ramp.tick",
         "steps.issue", "host_angle", "encoder_rpm", "store_q")
acc = [0] * len(names)
N = 1000
scratch = bytearray(4)
gc.collect()
a0 = gc.mem_alloc()
for i in range(N):
    time.sleep_ms(1)
    t0 = t(); core.service(); acc[0] += d(t(), t0)
    time.sleep_ms(1)
    now = core.clock.ticks_ms()
    t0 = t(); hal.update(); t1 = t()
    while core._ftab[irq.FTAB_Q_OUT] != core._ftab[irq.FTAB_Q_IN]:
        core._apply_next()
    if core.positioning and hal.position_reached():
        core.positioning = False
    t2 = t()
    core._check_stall(); core._check_tracking(); t3 = t()
    core._check_deadman(); t4 = t()
    store_q(core._cache[P.ANGLEMOVED], hal.angle_moved() + core.zero_offset, 12); t5 = t()
    switch.service(); t6 = t()
    console.poll(); t7 = t()
    acc[1] += d(t1, t0); acc[2] += d(t2, t1); acc[3] += d(t3, t2); acc[4] += d(t4, t3)
    acc[5] += d(t5, t4); acc[6] += d(t6, t5); acc[7] += d(t7, t6)
    time.sleep_ms(1)
    s = hal._steps; e = hal._enc; v = hal._vel; r = hal._ramp
    t0 = t(); s.poll(); t1 = t(); e.sample(); t2 = t(); v.update(e.count); t3 = t(); r.tick(); t4 = t()
    s.issue(r.x, 1000); t5 = t(); core._host_angle(); t6 = t(); hal.encoder_rpm(); t7 = t()
    store_q(scratch, 123456 + i, 12); t8 = t()
    acc[8] += d(t1, t0); acc[9] += d(t2, t1); acc[10] += d(t3, t2); acc[11] += d(t4, t3)
    acc[12] += d(t5, t4); acc[13] += d(t6, t5); acc[14] += d(t7, t6); acc[15] += d(t8, t7)
for k in range(len(names)):
    print("%-16s %7.1f us" % (names[k], acc[k] / N))
print("driver_rpm", hal.driver_rpm(), "flags", core.flags)
'''


# Which service() calls allocate on the chip (the host cycling): bytes, and what the call did.
ALLOC = '''
import gc, time
from joint import app
from joint.core import irq
from joint.core import controller as core
from joint.console import debug
from joint.spec import protocol as P
_service = core.JointController.service
_SETUP = bytearray((P.SETUP, 30, 10, 0, 0))
log = []
st = [0, 0]
class Done(BaseException):
    pass
def svc(self):
    if st[0] == 0:
        if self.ready:
            self.on_frame(_SETUP, 5)
            st[0] = 1
        return _service(self)
    q0 = self._ftab[irq.FTAB_Q_OUT]
    tr = self.transactions
    a0 = gc.mem_alloc()
    _service(self)
    a1 = gc.mem_alloc()
    if a1 != a0:
        log.append((a1 - a0, self._ftab[irq.FTAB_Q_OUT] - q0, self.transactions - tr, self._cache_turn, self.task_name))
    st[1] += 1
    if st[1] >= 600:
        raise Done()
core.JointController.service = svc
try:
    app.run()
except Done:
    pass
print("calls", st[1], "allocating", len(log))
for e in log[:40]:
    print(e)
'''


def main() -> int:
    problem = missing()
    if problem:
        print(f"chip_profile skipped: {problem}", file=sys.stderr)
        return 0
    ms = int(sys.argv[1]) if len(sys.argv) > 1 else 3000
    mode = sys.argv[2] if len(sys.argv) > 2 else "both"
    from bioscara import firmware_flash
    from chip import fsimage
    with tempfile.TemporaryDirectory() as directory:
        compile_mpy, _ = firmware_flash._compiler(fsimage.STOCK_PICO)
        files = dict(fsimage.joint_files(chip_bench.JOINT))
        files["/prof.py"] = PROFILER.format(n=len(TARGETS) + 1).encode()
        image = pathlib.Path(directory) / "prof.img"
        image.write_bytes(fsimage.littlefs_image(files))
        with EmulatedPico(image, plugins=chip_bench.JOINT_PLUGINS) as pico:
            if mode in ("both", "heap"):
                print(pico.exec(HEAP.format(modules=MODULES), soft_reset=True, timeout=600))
            if mode == "alloc":
                for prepare in chip_bench.BEFORE_LOOP:
                    prepare(pico)
                print(pico.exec(ALLOC, soft_reset=True, timeout=900))
            if mode == "parts":
                rpm = float(sys.argv[3]) if len(sys.argv) > 3 else 30.0
                print(pico.exec(PARTS.format(rpm=rpm), soft_reset=True, timeout=900))
            if mode in ("both", "time"):
                for prepare in chip_bench.BEFORE_LOOP:
                    prepare(pico)
                imports = "\n".join("try:\n    import %s\nexcept ImportError:\n    pass" % m
                                    for m in sorted({t[0] for t in TARGETS}))
                names = ["%s.%s" % (t[1], t[2]) for t in TARGETS]
                print(pico.exec(RUN.format(imports=imports, names=names, targets=TARGETS, ms=ms),
                                soft_reset=True, timeout=900))
    return 0


if __name__ == "__main__":
    sys.exit(main())
