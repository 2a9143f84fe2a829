"""`make bench-chip`: figures measured on the emulated Pico (rp2040js running the stock MicroPython
v1.28.0 UF2, the joint firmware deployed as `bioscara flash` deploys it). One `name value` line per
figure, the names stable across commits. The emulator models no flash wait states: every figure is
a lower bound for a real Pico.

Each producer in PRODUCERS returns {name: value}; add figures by adding a producer. The main-loop
run's joint board has the harness plugins in JOINT_PLUGINS (device models, the bus controller: see
chip/README.md), and each function in BEFORE_LOOP is called with the running EmulatedPico before
the measured run starts (to start the host's bus cycle, for example); emulated time is what
counts, so traffic a plugin schedules on the chip's clock is independent of this process's speed.
"""

from __future__ import annotations

import pathlib
import re
import sys
import tempfile
from typing import Any, Callable

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT)]

from bioscara import firmware_flash  # noqa: E402
from bioscara.firmware.console.debug_commands import TRACE_COLUMNS  # noqa: E402
from chip import fsimage  # noqa: E402
from chip.board import EmulatedPico  # noqa: E402
from chip.joint_devices import JOINT_DEVICES_PLUGIN  # noqa: E402
from chip.paths import missing  # noqa: E402
from chip.testing import read_console_until  # noqa: E402
from chip.i2c import joint_bus_plugin  # noqa: E402
from chip_bus import host_cycle  # noqa: E402

JOINT = "J1"
HEAP_JOINTS = ("J1", "J2")
LOOP_MS = 20_000  # the measured main loop, emulated milliseconds (the issue: >= 20,000 iterations)
TRACE_MS = 5_000  # the main loop again, with the original detector's trace on the console
# TMC2209, AS5600, rotor on its pins; the emulated I2C controller on its I2C0 (the joint bus)
JOINT_PLUGINS: list[dict[str, Any]] = [JOINT_DEVICES_PLUGIN, joint_bus_plugin(khz=400)]
BEFORE_LOOP: list[Callable[[EmulatedPico], None]] = [host_cycle]  # the host cycling at 100 Hz


def bench_image(directory: pathlib.Path) -> pathlib.Path:
    """The deployed joint's filesystem plus /chip_loop.mpy (the instrumentation, not firmware)."""
    compile_mpy, _ = firmware_flash._compiler(fsimage.STOCK_PICO)
    files = dict(fsimage.joint_files(JOINT))
    source = (ROOT / "bench" / "chip_loop.py").read_bytes()
    files["/chip_loop.mpy"] = compile_mpy(source, "chip_loop.py") if compile_mpy else source
    path = directory / "bench-littlefs.img"
    path.write_bytes(fsimage.littlefs_image(files))
    return path


# On the board, after a soft reset (fresh heap, main.py not run): the joint's own app.run() is timed.
LOOP_SCRIPT = """
from joint import app
from joint.core import controller as core
from joint.console import debug
import chip_loop
chip_loop.run({ms}, {trace})
"""
# The trace run's figures, as chip.trace.<name>; lines_per_s counts the trace lines the console
# printed while the loop was timed (J1 samples every 10 ms: 100 when none is dropped).
TRACE_FIGURES = ("chip.loop_hz", "chip.service_us_median", "chip.service_us_p99", "chip.service_us_max",
                 "chip.alloc_bytes_per_service")
TIMED_MARK = "chip.timed_from_here"  # bench/chip_loop.py prints it when timing starts


def _loop_output(ms: int, trace: bool) -> str:
    with tempfile.TemporaryDirectory() as directory:
        image = bench_image(pathlib.Path(directory))
        with EmulatedPico(image, plugins=JOINT_PLUGINS) as pico:
            for prepare in BEFORE_LOOP:
                prepare(pico)
            return pico.exec(LOOP_SCRIPT.format(ms=ms, trace=trace), soft_reset=True, timeout=600)


BOOTED = re.compile(rb"booted: (\d+) bytes of heap free")


def boot_heap_figures() -> dict[str, float]:
    """The heap free after boot as each joint logs it on its console, booted from its image as
    `bioscara flash` leaves it (main.py, no harness): the harness's own interned names would go into
    the board's never-freed string pool and could tip it into a new chunk (7.9 KB) that a joint
    never allocates. J1 is the issue's figure; J2 also loads the slow-contact detector."""
    figures = {}
    for joint in HEAP_JOINTS:
        with tempfile.TemporaryDirectory() as directory:
            image = pathlib.Path(directory) / f"{joint}-littlefs.img"
            fsimage.joint_image(joint, image)
            with EmulatedPico(image, plugins=JOINT_PLUGINS) as pico:
                booted = BOOTED.search(read_console_until(pico.port(), b"bytes of heap free", 300))
        suffix = "" if joint == JOINT else f".{joint.lower()}"
        figures[f"chip.heap_free_after_boot_kb{suffix}"] = int(booted.group(1)) / 1024 if booted else float("nan")
    return figures


def main_loop_figures() -> dict[str, float]:
    return parse_figures(_loop_output(LOOP_MS, trace=False))


def trace_loop_figures() -> dict[str, float]:
    """The main loop with `trace on` (the issue: it must still hold 1 kHz)."""
    out = _loop_output(TRACE_MS, trace=True)
    figures = parse_figures(out)
    timed = out.split(TIMED_MARK, 1)[1] if TIMED_MARK in out else ""
    lines = sum(1 for line in timed.splitlines() if len(line.split("\t")) == len(TRACE_COLUMNS))
    result = {name.replace("chip.", "chip.trace.", 1): figures[name] for name in TRACE_FIGURES if name in figures}
    if "chip.loop_seconds" in figures:
        result["chip.trace.lines_per_s"] = lines / figures["chip.loop_seconds"]
    return result


def parse_figures(out: str) -> dict[str, float]:
    figures = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 2 and parts[0].startswith("chip."):
            figures[parts[0]] = float(parts[1])
    return figures


def bus_figures() -> dict[str, float]:
    """The joint-bus figures (bench/chip_bus.py): legacy transactions and cycles, then protocol v2."""
    import chip_bus
    return chip_bus.deployed_figures()


def circuitpython_figures() -> dict[str, float]:
    """The CircuitPython joint's figures (bench/chip_cp.py, chip.cp.*), where its UF2 is present."""
    problem = missing("circuitpython")
    if problem:
        print(f"chip.cp figures skipped: {problem}", file=sys.stderr)
        return {}
    import chip_cp
    return chip_cp.circuitpython_figures()


PRODUCERS: list[Callable[[], dict[str, float]]] = [boot_heap_figures, main_loop_figures, trace_loop_figures, bus_figures,
                                                   circuitpython_figures]


def main() -> int:
    problem = missing()
    if problem:
        print(f"bench-chip skipped: {problem}", file=sys.stderr)
        return 0
    for produce in PRODUCERS:
        for name, value in produce().items():
            print(f"{name} {value:g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
