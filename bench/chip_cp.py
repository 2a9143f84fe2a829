"""CircuitPython joint figures for `make bench-chip` (`chip.cp.*`): J1 flashed as
`bioscara flash --runtime circuitpython` leaves CIRCUITPY, on the emulated Pico with its devices and
the joint bus, every figure in emulated time.

* `chip.cp.heap_free_after_boot`: bytes of heap free when the loop starts (after a collection);
* `chip.cp.scl_held_us.<kHz>.{median,p99,max}`: SCL held by the joint as flashed (no meter in
  its loop: a report, every METER_ITERATIONS iterations, held SCL 18-24 ms) per register transaction
  as the original host makes it (REGISTERS, SAMPLES transactions each, gaps sweeping the loop's
  1 ms phase), and `chip.cp.scl_held_us.<kHz>.<REGISTER>` each register's median;
  `chip.cp.failed_transactions` counts NAKs and stretch timeouts, `chip.cp.wrong_replies` replies
  of the registers that do not change at rest (STATIC) that differ from their first reply;
* `chip.cp.scl_held_us.cycling.{median,p99,max}`: SCL held over CYCLES cycles of the original
  host at 100 Hz (chip_bus: its SETRPM turns the motor), on the same joint, after those:
  the host a moving joint serves for minutes (collections land among them), `.over_1ms` how
  many of them held SCL over 1 ms,
  `chip.cp.cycling_failed_transactions` its NAKs and stretch timeouts;
* on a second boot, enabled, with the original host cycling at 100 Hz in the background
  (chip_bus.host_cycle: its SETRPM turns the motor), the loop's own figures
  (firmware/joint/cpy/app.py LoopMeter, over 5 x METER_ITERATIONS iterations):
  `chip.cp.loop_hz`, `chip.cp.iteration_us.{median,p99,max}` (the work before the wait for the
  next tick, of every 5th iteration), `chip.cp.alloc_bytes_per_iteration`, `chip.cp.collections_per_s`,
  `chip.cp.collect_us.{mean,max}` (the meter's own clock reads are taken off the allocation).
"""

from __future__ import annotations

import contextlib
import statistics
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "bench")]

from bioscara import circuitpy  # noqa: E402
from chip import fsimage  # noqa: E402
from chip.board import EmulatedPico  # noqa: E402
from chip.i2c import JointBusClient, joint_bus_plugin  # noqa: E402
from chip.joint_devices import JOINT_DEVICES_PLUGIN  # noqa: E402
from chip_bus import (CYCLE_NAMES, CYCLE_PERIOD_US, HOST_CLOCK_PPM, enable, host_cycle,  # noqa: E402
                      legacy_transaction)

REGISTERS = ("PING", "ANGLEMOVED", "GETENCODERRPM", "GETPIDERROR", "IDENTITY", "LASTERROR")
SAMPLES = 10  # transactions per register and bus speed
PHASE_STEP_US = 37  # each gap 37 us longer than the one before: the requests sweep the loop's phase
STATIC = ("PING", "IDENTITY", "LASTERROR")  # the others follow the encoder, settling after boot
METER_ITERATIONS = 200  # one report's timed iterations (every 5th: LoopMeter.STRIDE)
SPEEDS_KHZ = (100, 400)
CYCLES = 300  # the cycling host's cycles: 900 transactions, 3 s of the joint moving


def bench_code(meter_every: int) -> bytes:
    return f"from joint.cpy import app\n\napp.run(meter_every={meter_every})\n".encode()


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def _read_console(console, until: bytes, timeout: float, seen: bytes = b"") -> bytes:
    end = time.monotonic() + timeout
    while until not in seen and time.monotonic() < end:
        seen += console.read(4096)
    return seen


def scl_figures(bus: JointBusClient, drain: Callable[[], object]) -> dict[str, float]:
    """`drain()` after each transaction reads what the joint printed: CircuitPython's console
    output waits, and the loop with it, once the host stops reading the USB serial port."""
    figures: dict[str, float] = {}
    failed = wrong = 0
    for khz in SPEEDS_KHZ:
        bus.set_khz(khz)
        held: list[float] = []
        for name in REGISTERS:
            write, read_len = legacy_transaction(name)
            mine, first = [], None
            for i in range(SAMPLES):
                t = bus.transfer(0x11, write, read_len, gap_us=1000 + i * PHASE_STEP_US)
                drain()
                first = t.data if first is None else first
                if not t.ack or t.timed_out:
                    failed += 1
                elif name in STATIC and t.data != first:
                    wrong += 1
                mine.append(t.scl_held_us)
            figures[f"chip.cp.scl_held_us.{khz}.{name}"] = round(statistics.median(mine), 1)
            held += mine
        figures[f"chip.cp.scl_held_us.{khz}.median"] = round(statistics.median(held), 1)
        figures[f"chip.cp.scl_held_us.{khz}.p99"] = round(percentile(held, 0.99), 1)
        figures[f"chip.cp.scl_held_us.{khz}.max"] = round(max(held), 1)
    bus.set_khz(400)
    figures["chip.cp.failed_transactions"] = failed
    figures["chip.cp.wrong_replies"] = wrong
    return figures


def cycling_figures(bus: JointBusClient) -> dict[str, float]:
    """SCL held over CYCLES cycles of the original host at 100 Hz, 400 kHz (module docstring)."""
    cycle = [(0x11, *legacy_transaction(n)) for n in CYCLE_NAMES]
    done = bus.schedule(cycle, repeat=CYCLES, period_us=CYCLE_PERIOD_US * (1 + HOST_CLOCK_PPM * 1e-6),
                        timeout=900)
    held = [t.scl_held_us for t in done]
    return {"chip.cp.scl_held_us.cycling.median": round(statistics.median(held), 1),
            "chip.cp.scl_held_us.cycling.p99": round(percentile(held, 0.99), 1),
            "chip.cp.scl_held_us.cycling.max": round(max(held), 1),
            "chip.cp.scl_held_us.cycling.over_1ms": sum(h > 1000 for h in held),
            "chip.cp.cycling_failed_transactions": sum(not t.ack or t.timed_out for t in done)}


@contextlib.contextmanager
def _joint(meter_every: int) -> Iterator[tuple[EmulatedPico, Any, bytes]]:
    """J1 booted from the flashed image (its loop metered when `meter_every` > 0): the pico, its
    console and what the console printed up to the loop's start."""
    import serial

    files = dict(circuitpy.build_image("J1").files)
    if meter_every:
        files[circuitpy.CODE_PATH] = bench_code(meter_every)
    with tempfile.TemporaryDirectory() as directory:
        image = Path(directory) / "circuitpy.img"
        image.write_bytes(fsimage.fat_image(files))
        plugins = [JOINT_DEVICES_PLUGIN, joint_bus_plugin(khz=400)]
        with EmulatedPico(image, runtime="circuitpython", plugins=plugins) as pico, \
                serial.Serial(pico.port(), timeout=0.2) as console:
            yield pico, console, _read_console(console, b"collecting every", 600)


def circuitpython_figures() -> dict[str, float]:
    figures: dict[str, float] = {}
    with _joint(0) as (pico, console, seen):  # the joint as flashed: no meter in its loop
        line = seen.split(b"CircuitPython joint: ", 1)[1].split(b" bytes", 1)[0]
        figures["chip.cp.heap_free_after_boot"] = int(line)
        bus = JointBusClient(pico)
        if not enable(bus):
            raise RuntimeError("the CircuitPython joint did not enable (SETUP)")
        drain = lambda: console.read(console.in_waiting)  # noqa: E731
        figures.update(scl_figures(bus, drain))
        figures.update(cycling_figures(bus))
        drain()
    for name, value in figures.items():  # partial figures survive a later failure
        print(f"{name} {value:g}", file=sys.stderr)
    with _joint(METER_ITERATIONS) as (pico, console, _):
        bus = JointBusClient(pico)
        if not enable(bus):
            raise RuntimeError("the CircuitPython joint did not enable (SETUP)")
        host_cycle(pico)
        # The first report may cover the enabling; the second is the host's cycle alone.
        seen = _read_console(console, b"cp.heap.free", 900)
        if b"cp.heap.free" not in seen:
            raise RuntimeError("the CircuitPython joint's loop reported no figures")
        seen = _read_console(console, b"cp.heap.free", 900, seen.rsplit(b"cp.heap.free", 1)[1])
        report = seen.decode(errors="replace")
    names = {"cp.loop.hz": "chip.cp.loop_hz", "cp.loop.iteration_us.median": "chip.cp.iteration_us.median",
             "cp.loop.iteration_us.p99": "chip.cp.iteration_us.p99", "cp.loop.iteration_us.max": "chip.cp.iteration_us.max",
             "cp.loop.alloc_bytes_per_iteration": "chip.cp.alloc_bytes_per_iteration",
             "cp.gc.collections_per_s": "chip.cp.collections_per_s", "cp.gc.collect_us.mean": "chip.cp.collect_us.mean",
             "cp.gc.collect_us.max": "chip.cp.collect_us.max", "cp.heap.free": "chip.cp.heap_free_in_loop"}
    for line in report.splitlines():
        parts = line.split()
        if len(parts) == 2 and parts[0] in names:
            figures[names[parts[0]]] = float(parts[1])
    return figures


def main() -> int:
    from chip.paths import missing

    problem = missing("circuitpython")
    if problem:
        print(f"chip.cp figures skipped: {problem}", file=sys.stderr)
        return 0
    for name, value in circuitpython_figures().items():
        print(f"{name} {value:g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
