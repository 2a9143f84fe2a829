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
import sys
import tempfile
from typing import Any, Callable

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT)]

from bioscara import flash  # noqa: E402
from chip import fsimage  # noqa: E402
from chip.board import EmulatedPico  # noqa: E402
from chip.joint_devices import JOINT_DEVICES_PLUGIN  # noqa: E402
from chip.paths import missing  # noqa: E402
from chip.i2c import joint_bus_plugin  # noqa: E402
from chip_bus import host_cycle  # noqa: E402

JOINT = "J1"
LOOP_MS = 20_000  # the measured main loop, emulated milliseconds (the issue: >= 20,000 iterations)
# TMC2209, AS5600, rotor on its pins; the emulated I2C controller on its I2C0 (the joint bus)
JOINT_PLUGINS: list[dict[str, Any]] = [JOINT_DEVICES_PLUGIN, joint_bus_plugin(khz=400)]
BEFORE_LOOP: list[Callable[[EmulatedPico], None]] = [host_cycle]  # the host cycling at 100 Hz


def bench_image(directory: pathlib.Path) -> pathlib.Path:
    """The deployed joint's filesystem plus /chip_loop.mpy (the instrumentation, not firmware)."""
    compile_mpy, _ = flash._compiler(fsimage.STOCK_PICO)
    files = dict(fsimage.joint_files(JOINT))
    source = (ROOT / "bench" / "chip_loop.py").read_bytes()
    files["/chip_loop.mpy"] = compile_mpy(source, "chip_loop.py") if compile_mpy else source
    path = directory / "bench-littlefs.img"
    path.write_bytes(fsimage.littlefs_image(files))
    return path


# On the board, after a soft reset (fresh heap, main.py not run): what chip_loop itself occupies
# is measured and added back to the heap figure; then the joint's own app.run() is timed.
LOOP_SCRIPT = """
import gc
from joint import app, core, debug
gc.collect()
_before = gc.mem_free()
import chip_loop
gc.collect()
chip_loop.run({ms}, _before - gc.mem_free())
"""


def main_loop_figures() -> dict[str, float]:
    with tempfile.TemporaryDirectory() as directory:
        image = bench_image(pathlib.Path(directory))
        with EmulatedPico(image, plugins=JOINT_PLUGINS) as pico:
            for prepare in BEFORE_LOOP:
                prepare(pico)
            out = pico.exec(LOOP_SCRIPT.format(ms=LOOP_MS), soft_reset=True, timeout=600)
    return parse_figures(out)


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


PRODUCERS: list[Callable[[], dict[str, float]]] = [main_loop_figures, bus_figures]


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
