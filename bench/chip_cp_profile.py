"""`python bench/chip_cp_profile.py [iterations] [rpm]`: where the CircuitPython joint's main-loop
time and allocations go, on the emulated Pico (J1 as `bioscara flash --runtime circuitpython`
leaves CIRCUITPY, its devices attached, enabled and turning at `rpm`, no bus traffic).

Each function in PARTS is wrapped to add up its calls, inclusive microseconds and bytes
allocated; one pass times (gc.mem_alloc walks the heap: it stays out of the timed window), a
second counts bytes. The wrappers' own cost (time.monotonic_ns allocates a long int) is measured
on an empty function and taken off. The BASE rows are the interpreter's floor: an empty loop
iteration, a call, the clock. A tool for finding costs, not a figure: the figures are
bench/chip_cp.py's.
"""

from __future__ import annotations

import pathlib
import sys
import tempfile
import time

import serial

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "bench")]

from bioscara import circuitpy  # noqa: E402
from chip import fsimage  # noqa: E402
from chip.board import EmulatedPico  # noqa: E402
from chip.joint_devices import JOINT_DEVICES_PLUGIN  # noqa: E402
from chip.paths import missing  # noqa: E402

DONE = b"BASE ((w + m)"  # the last line the board prints
# (module, owner: a class name or "" for the module's own globals, name, arguments with self)
PARTS = [
    ("joint.core.controller", "JointController", "service", 1),
    ("joint.pico.motor", "PicoStepper", "update", 1),
    ("joint.pico.motor", "", "poll_steps", 3),
    ("joint.pico.motor", "", "_enc_next", 5),
    ("joint.pico.motor", "", "update_velocity", 2),
    ("joint.pico.motor", "", "_resync", 4),
    ("joint.pico.motor", "", "run_ramp", 2),
    ("joint.pico.motor", "", "issue_steps", 5),
    ("joint.pico.motor", "PicoStepper", "angle_moved", 1),
    ("joint.pico.motor", "PicoStepper", "encoder_rpm", 1),
    ("joint.pico.motor", "PicoStepper", "driver_rpm", 1),
    ("joint.pico.motor", "PicoStepper", "position_reached", 1),
    ("joint.core.loop", "", "store_q", 3),
    ("joint.core.controller", "JointController", "_sample_detectors", 2),
    ("joint.core.controller", "JointController", "_check_deadman", 1),
    ("joint.console.debug", "DebugConsole", "poll", 1),
    ("joint.links.cp_target", "CircuitPythonTargetAdapter", "poll", 1),
]

PROFILE = '''
import gc, struct, sys, time, supervisor
from joint.cpy import app as cpapp
from joint.console.debug import DebugConsole
from joint.spec import protocol as P
for _m in {modules!r}:
    __import__(_m)
ns = time.monotonic_ns
ticks_ms = supervisor.ticks_ms
N = {iterations}
PARTS = {parts!r}
US = [0] * (len(PARTS) + 1)
BYTES = [0] * (len(PARTS) + 1)
CALLS = [0] * (len(PARTS) + 1)
MODE = [0]  # 0: time, 1: bytes

# One wrapper per arity: *args would allocate a tuple a call.
WRAPPER = """
def w({{a}}):
    if MODE[0]:
        b = gc.mem_alloc()
        r = f({{a}})
        BYTES[i] += gc.mem_alloc() - b
    else:
        t = ns()
        r = f({{a}})
        US[i] += ns() - t
        CALLS[i] += 1
    return r
"""

def wrap(f, i, arity):
    scope = {{"f": f, "i": i, "MODE": MODE, "BYTES": BYTES, "US": US, "CALLS": CALLS, "gc": gc, "ns": ns}}
    exec(WRAPPER.format(a=", ".join("a%d" % k for k in range(arity))), scope)
    return scope["w"]

def _empty():
    return None

for i, (mod, owner, name, arity) in enumerate(PARTS):
    m = sys.modules[mod]
    target = getattr(m, owner) if owner else m
    setattr(target, name, wrap(getattr(target, name), i, arity))
empty = wrap(_empty, len(PARTS), 0)

core, cfg, log = cpapp.boot()
link = cpapp.join_bus(core, cfg, log)
console = cpapp.SerialConsole()
debug = DebugConsole(core, console.read, console.write)
core.on_frame(bytearray((P.SETUP, 30, 10, 0, 0)), 5)
frame = bytearray(5)
frame[0] = P.SETRPM
struct.pack_into("<f", frame, 1, {rpm})
core.on_frame(frame, 5)

def next_tick():
    t = ticks_ms()
    while ticks_ms() == t:
        pass

def iteration():
    next_tick()
    core.host_seen()  # a host polling: the deadman stays quiet
    link.poll()
    core.service()
    debug.poll()
    empty()

print("profiling: heap free", gc.mem_free())
for mode in (0, 1):
    MODE[0] = mode
    print("pass", mode)
    for k in range(N // 4):  # settle: the ramp at speed
        iteration()
    for i in range(len(US)):
        if mode:
            BYTES[i] = 0
        else:
            US[i] = CALLS[i] = 0
    gc.collect()
    gc.disable()
    for k in range(N):
        iteration()
        if k % 4 == 3:
            gc.collect()
    gc.enable()
overhead = US[-1] / CALLS[-1] / 1000
overhead_bytes = BYTES[-1] / CALLS[-1]
print("wrapper overhead %.1f us, %.1f bytes a call (taken off below)" % (overhead, overhead_bytes))
print("%-42s %8s %8s %9s %10s" % ("part", "calls/it", "us each", "us/iter", "bytes/iter"))
for i, (mod, owner, name, arity) in enumerate(PARTS):
    if CALLS[i]:
        calls = CALLS[i]
        print("%-42s %8.2f %8.1f %9.1f %10.1f" % (
            (owner or mod.split(".")[-1]) + "." + name, calls / N, US[i] / 1000 / calls - overhead,
            (US[i] / 1000 - overhead * calls) / N, (BYTES[i] - overhead_bytes * calls) / N))

def base(label, fn):
    gc.collect()
    a = gc.mem_alloc()
    t = ns()
    fn()
    spent = (ns() - t) / 1000 / 1000
    print("BASE %-40s %8.2f us %8.1f bytes" % (label, spent, (gc.mem_alloc() - a) / 1000))

def empty_loop():
    for i in range(1000):
        pass

def calls():
    for i in range(1000):
        _empty()

def clock_ns():
    for i in range(1000):
        ns()

def clock_core():
    tu = core.clock.ticks_us
    for i in range(1000):
        tu()

def clock_ns_us():
    for i in range(1000):
        ns() // 1000

def clock_ms():
    for i in range(1000):
        ticks_ms()

def wide_mask():
    m = 1
    m <<= 31
    k = m + m - 1
    w = 5
    for i in range(1000):
        ((w + m) & k) - m

base("empty loop iteration", empty_loop)
base("call of an empty function", calls)
base("time.monotonic_ns()", clock_ns)
base("time.monotonic_ns() // 1000", clock_ns_us)
base("core.clock.ticks_us()", clock_core)
base("supervisor.ticks_ms()", clock_ms)
base("((w + m) & k) - m, m = 2**31", wide_mask)
'''


def main() -> int:
    problem = missing("circuitpython")
    if problem:
        print(f"chip_cp_profile skipped: {problem}", file=sys.stderr)
        return 0
    iterations = int(sys.argv[1]) if len(sys.argv) > 1 else 200
    rpm = float(sys.argv[2]) if len(sys.argv) > 2 else 30.0
    code = PROFILE.format(modules=sorted({p[0] for p in PARTS}), iterations=iterations, parts=PARTS, rpm=rpm)
    compile_mpy, _ = circuitpy._compiler()
    files = dict(circuitpy.build_image("J1").files)
    # Run as code.py from a precompiled module: compiled in the raw REPL, it left too little heap.
    files["/lib/cp_profile.mpy"] = compile_mpy(code.encode(), "cp_profile.mpy")
    files[circuitpy.CODE_PATH] = b"import cp_profile\n"
    with tempfile.TemporaryDirectory() as directory:
        image = pathlib.Path(directory) / "circuitpy.img"
        image.write_bytes(fsimage.fat_image(files))
        with EmulatedPico(image, runtime="circuitpython", plugins=[JOINT_DEVICES_PLUGIN]) as pico, \
                serial.Serial(pico.port(), timeout=0.2) as console:
            seen = b""
            end = time.monotonic() + 1800
            while DONE not in seen and b"Error" not in seen and time.monotonic() < end:
                seen += console.read(4096)
            seen += console.read(4096)
    print(seen.decode(errors="replace"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
