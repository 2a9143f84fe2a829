"""Joint-bus figures for `make bench-chip`: the deployed joint's I2C0 target under the emulated
controller (chip/src/joint_bus.mjs), every figure in emulated microseconds.

* `chip.scl_held_us.<REGISTER>` / `chip.irq_cpu_us.<REGISTER>`: one transaction as the original
  host makes it (a read: [reg], repeated START, payload + flags; a command: [reg, payload], repeated
  START, the flags), at 400 kHz, the median of REPEATS transactions a few ms apart. SCL held is the
  time the target kept SCL low; IRQ CPU is the joint core's time in its I2C0 interrupt handler from
  the START until the handler is idle after the STOP (nested interrupts excluded).
* `chip.cycle_us.<kHz>`: the original host's per-joint cycle, ANGLEMOVED read, GETENCODERRPM read,
  SETRPM command, back to back, START of the first to STOP of the last, stretching included;
  the median over CYCLES cycles at 100 Hz; `chip.cycle_failures.<kHz>` counts the cycles with a
  failed transaction (a NAK, or SCL held past the controller's 35 ms stretch timeout: the joint
  wedged the bus, see chip/README.md), which are left out of the median.

* `chip.scl_held_us.v2` / `chip.irq_cpu_us.v2`: one protocol v2 transaction (7-byte mailbox
  write, repeated START, 8-byte state read) at 400 kHz, after the legacy switch (PROTOCOL = 2) and
  the sync; `chip.cycle_us.v2.<kHz>`: one joint's v2 cycle (that one transaction) cycled at 100 Hz;
  `chip.cycle_wall_over_wire.v2.400`: its span over its wire time (156 bit times) at 400 kHz. The
  frame is a NONE poll repeated with one seq (a retry to the joint): mem mode serves it from C
  either way, so the bus timing is that of any v2 frame.

The joint is enabled first (SETUP, sent at 100 kHz: at 400 kHz the rp2 driver splits 5-byte
commands, see chip/README.md) when the device fakes are on its pins; without them it is disabled
and answers with its flags. `transaction_figures` is the generic per-transaction API (v2 frames too).
"""

from __future__ import annotations

import statistics
import sys
from collections.abc import Iterable, Sequence
from typing import Any

ROOT = __import__("pathlib").Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT)]

from bioscara.firmware.spec import protocol as P  # noqa: E402
from bioscara.firmware.spec import protocol_v2 as V  # noqa: E402
from chip.board import EmulatedPico  # noqa: E402
from chip.i2c import JointBusClient, Transaction, joint_bus_plugin  # noqa: E402

ADDRESS = 0x11  # J1
REGISTERS = ("PING", "ANGLEMOVED", "GETENCODERRPM", "SETRPM", "MOVETOANGLE", "IDENTITY")
SPEEDS_KHZ = (100, 400, 1000)
REPEATS = 7
CYCLES = 10
GAP_US = 3000.0
CYCLE_PERIOD_US = 10_000.0  # host cycling at 100 Hz
# The background host's clock runs 300 ppm off the joint's, as two boards' clocks do (if less):
# at exactly 10 ms the cycle would meet the joint's 1 ms loop at one phase for the whole run, set
# by the boot, and the main-loop figures would measure that phase alone. Off by 3 us a cycle, it
# sweeps every phase of the loop every 3.3 s.
HOST_CLOCK_PPM = 300
CYCLE_NAMES = ("ANGLEMOVED", "GETENCODERRPM", "SETRPM")  # the original host's per-joint cycle
COMMAND_VALUES = {"SETRPM": (10.0,), "MOVETOANGLE": (1.0,), "SETUP": (30, 10, 0, 0)}


def legacy_transaction(name: str) -> tuple[bytes, int]:
    """(write, read_len) of register `name` as the original host uses it."""
    reg = P.register(name)
    if reg.writable:
        return bytes([reg.addr]) + reg.encode(*COMMAND_VALUES[name]), 1
    return bytes([reg.addr]), reg.rsize + 1


def wait_on_bus(bus: JointBusClient, address: int = ADDRESS, limit: int = 500) -> None:
    """Probe until the joint has booted and joined the bus (it ignores its address until then)."""
    for _ in range(limit):
        if bus.transfer(address, None, 0, gap_us=20_000).ack:
            return
    raise RuntimeError(f"the joint at 0x{address:02x} never joined the bus")


def transaction_figures(bus: JointBusClient, write: bytes, read_len: int, *, repeats: int = REPEATS,
                        address: int = ADDRESS) -> tuple[float, float, list[Transaction]]:
    """Median SCL held and IRQ CPU time (us) of one transaction repeated `repeats` times, isolated."""
    done = [bus.transfer(address, write, read_len, gap_us=GAP_US) for _ in range(repeats)]
    held = statistics.median(t.scl_held_us for t in done)
    irq = statistics.median(t.irq_cpu_us or 0.0 for t in done)
    return held, irq, done


def cycle_figure(bus: JointBusClient, items: Sequence[tuple[bytes, int]], *, cycles: int = CYCLES,
                 address: int = ADDRESS) -> tuple[float | None, int]:
    """`items` back to back, cycled at 100 Hz: the median time (us) from the first START to the
    last STOP over the cycles whose transactions all completed, and how many cycles failed (a NAK,
    or SCL held past the stretch timeout)."""
    done = bus.schedule([(address, w, r) for w, r in items], repeat=cycles, period_us=CYCLE_PERIOD_US,
                        gap_us=0.0)
    n = len(items)
    groups = [done[i:i + n] for i in range(0, len(done), n)]
    spans = [g[-1].start_us + g[-1].total_us - g[0].start_us for g in groups if all(t.ack for t in g)]
    return (statistics.median(spans) if spans else None), len(groups) - len(spans)


def enable(bus: JointBusClient) -> bool:
    """SETUP at 100 kHz; True if the joint reports itself enabled."""
    bus.set_khz(100)
    write, read_len = legacy_transaction("SETUP")
    flags = bus.transfer(ADDRESS, write, read_len, gap_us=GAP_US).data[0]
    bus.set_khz(400)
    return not flags & P.FLAG_NOTENABLED


def host_cycle(pico: EmulatedPico, seconds: float = 60.0) -> None:
    """The original host cycling at 100 Hz (by its own clock, HOST_CLOCK_PPM) at 400 kHz in the
    background (for the main-loop run): the 3-transaction cycle; NAKed while the joint is not on
    the bus."""
    cycle = [(ADDRESS, *legacy_transaction(n)) for n in CYCLE_NAMES]
    period_us = CYCLE_PERIOD_US * (1 + HOST_CLOCK_PPM * 1e-6)
    JointBusClient(pico).start_cycle(cycle, period_us=period_us, repeat=round(seconds * 1e6 / period_us))


def switch_to_v2(bus: JointBusClient, address: int = ADDRESS) -> bytes:
    """The legacy PROTOCOL = 2 command as our host sends it, then NONE frames until the joint
    acknowledges one (a state read in a transaction shows the frame before: its write is taken by
    the next main-loop pass); returns that frame (a v2 transaction's 7-byte write)."""
    write = bytes([P.PROTOCOL]) + P.register("PROTOCOL").encode(V.PROTOCOL_V2)
    bus.transfer(address, write, 1, gap_us=GAP_US)
    frame = b""
    for seq in range(1, 60):
        state = V.decode_state(address, bus.transfer(
            address, V.encode_frame(address, V.CMD_NONE, b"", seq), V.STATE_SIZE, gap_us=GAP_US).data)
        if state is not None and seq > 1 and state[-1] == seq - 1:
            return frame
        frame = V.encode_frame(address, V.CMD_NONE, b"", seq)
    raise RuntimeError(f"the joint at 0x{address:02x} never acknowledged a v2 frame")


def v2_figures(image: Any, plugins: Iterable[dict[str, Any]] = ()) -> dict[str, float]:
    """The v2 figures on a freshly booted joint (the legacy cycle at 1 MHz may wedge the bus)."""
    with EmulatedPico(image, plugins=[*plugins, joint_bus_plugin(khz=400)]) as pico:
        bus = JointBusClient(pico)
        wait_on_bus(bus)
        return v2_bus_figures(bus)


def v2_bus_figures(bus: JointBusClient) -> dict[str, float]:
    figures: dict[str, float] = {}
    bus.set_khz(400)
    frame = switch_to_v2(bus)
    held, irq, _ = transaction_figures(bus, frame, V.STATE_SIZE)
    figures["chip.scl_held_us.v2"] = round(held, 1)
    figures["chip.irq_cpu_us.v2"] = round(irq, 1)
    wire_bits = P.wire_bits(len(frame), V.STATE_SIZE)
    for khz in SPEEDS_KHZ:
        bus.set_khz(khz)
        span, failed = cycle_figure(bus, [(frame, V.STATE_SIZE)])
        if span is not None:
            figures[f"chip.cycle_us.v2.{khz}"] = round(span, 1)
            if khz == 400:
                figures["chip.cycle_wall_over_wire.v2.400"] = round(span / (wire_bits * 1000 / khz), 3)
        figures[f"chip.cycle_failures.v2.{khz}"] = failed
    bus.set_khz(400)
    return figures


def bus_figures(image: Any, plugins: Iterable[dict[str, Any]] = ()) -> dict[str, float]:
    figures: dict[str, float] = {}
    with EmulatedPico(image, plugins=[*plugins, joint_bus_plugin(khz=400)]) as pico:
        bus = JointBusClient(pico)
        wait_on_bus(bus)
        enable(bus)
        for name in REGISTERS:
            held, irq, _ = transaction_figures(bus, *legacy_transaction(name))
            figures[f"chip.scl_held_us.{name}"] = round(held, 1)
            figures[f"chip.irq_cpu_us.{name}"] = round(irq, 1)
        cycle = [legacy_transaction(n) for n in CYCLE_NAMES]
        for khz in SPEEDS_KHZ:
            bus.set_khz(khz)
            span, failed = cycle_figure(bus, cycle)
            if span is not None:
                figures[f"chip.cycle_us.{khz}"] = round(span, 1)
            figures[f"chip.cycle_failures.{khz}"] = failed
            if failed:
                break  # the joint wedged the bus (SCL held): later figures would measure timeouts
    return figures


def deployed_figures(producers: Sequence[Any] = (bus_figures, v2_figures)) -> dict[str, float]:
    """`producers` (image, plugins) -> figures on the deployed J1 with its device fakes."""
    import tempfile
    from pathlib import Path

    from chip import fsimage
    from chip.joint_devices import JOINT_DEVICES_PLUGIN

    figures: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as directory:
        image = Path(directory) / "J1.img"
        fsimage.joint_image("J1", image)
        for produce in producers:
            figures.update(produce(image, [JOINT_DEVICES_PLUGIN]))
    return figures


def main() -> int:
    """The figures alone (`make bench-chip` runs them with the others)."""
    from chip.paths import missing

    problem = missing()
    if problem:
        print(f"chip bus figures skipped: {problem}", file=sys.stderr)
        return 0
    for name, value in deployed_figures().items():
        print(f"{name} {value:g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
