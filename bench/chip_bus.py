"""Joint-bus figures for `make bench-chip`: the deployed joint's I2C0 target under the emulated
controller (chip/src/joint_bus.mjs), every figure in emulated microseconds.

* Every register of the map, as a host uses it, at 400 kHz: REPEATS isolated transactions each, a
  few ms apart and sweeping the phase of the joint's 1 ms main loop. `chip.scl_held_us.<NAME>` /
  `chip.irq_cpu_us.<NAME>` the median, `chip.scl_held_us_max.<NAME>` / `chip.irq_cpu_us_max.<NAME>`
  the largest. NAME is a register (a read: [reg], repeated START, payload + flags; a command:
  [reg, payload], repeated START, the flags; a register declared but not implemented: [reg] and
  its flags, rejected), `read.<REGISTER>` the read of a register that is also a command, or
  `reject.<reason>` a frame the joint rejects (see REJECTED). SCL held is the time the target kept
  SCL low; IRQ CPU is the joint core's time in its I2C0 interrupt handler from the START until
  the handler is idle after the STOP (nested interrupts excluded). Every case checks the reply's
  ERROR flag: a case that does not take the path it names fails the run.
* `chip.worst.<figure>`: the largest of each figure over all of them, `chip.over_limit.<figure>`
  how many exceed LIMITS_US (SCL held 120 us, IRQ CPU 150 us); the worst cases are named on stderr.
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
commands, see chip/README.md); that needs the device fakes on its pins (without them it is
disabled, and the register figures refuse to run). `transaction_figures` is the generic
per-transaction API (v2 frames too).
"""

from __future__ import annotations

import statistics
import struct
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

ROOT = __import__("pathlib").Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT)]

from bioscara.firmware.spec import protocol as P  # noqa: E402
from bioscara.firmware.spec import protocol_v2 as V  # noqa: E402
from chip.board import EmulatedPico  # noqa: E402
from chip.i2c import JointBusClient, Transaction, joint_bus_plugin  # noqa: E402

ADDRESS = 0x11  # J1
SPEEDS_KHZ = (100, 400, 1000)
REPEATS = 9
CYCLES = 10
GAP_US = 3000.0
# Each repeat starts this much later in the joint's 1 ms main loop than the one before: the
# repeats sweep the loop's phases (a transaction meeting the loop's critical sections, or an
# iteration that applies a command, is among them).
PHASE_STEP_US = 111.0
CYCLE_PERIOD_US = 10_000.0  # host cycling at 100 Hz
# The background host's clock runs 300 ppm off the joint's, as two boards' clocks do (if less):
# at exactly 10 ms the cycle would meet the joint's 1 ms loop at one phase for the whole run, set
# by the boot, and the main-loop figures would measure that phase alone. Off by 3 us a cycle, it
# sweeps every phase of the loop every 3.3 s.
HOST_CLOCK_PPM = 300
CYCLE_NAMES = ("ANGLEMOVED", "GETENCODERRPM", "SETRPM")  # the original host's per-joint cycle
# Every command's payload in the bench: accepted by the enabled joint at rest.
COMMAND_VALUES: dict[str, tuple[Any, ...]] = {
    "SETUP": (30, 10, 0, 0), "SETRPM": (10.0,), "MOVESTEPS": (256,), "MOVEANGLE": (1.0,),
    "MOVETOANGLE": (1.0,), "SETCURRENT": (30,), "SETHOLDCURRENT": (10,),
    "SETMAXACCELERATION": (2000.0,), "SETMAXDECELERATION": (2000.0,), "SETMAXVELOCITY": (1000.0,),
    "ENABLESTALLGUARD": (10,), "DISABLESTALLGUARD": (0,), "CLEARSTALL": (0,), "SETBRAKEMODE": (1,),
    "ENABLECLOSEDLOOP": (0,), "DISABLECLOSEDLOOP": (0,), "STOP": (0,), "CHECKORIENTATION": (10.0,),
    "HOME": (1, 30, 200, 30), "HOMEOFFSET": (0.0,), "PROTOCOL": (1,), "WATCHDOG": (0,),
}
# A blocking command is accepted only once the one before it was stopped.
BEFORE_EACH = {"HOME": ("STOP",), "CHECKORIENTATION": ("STOP",)}
LIMITS_US = {"scl_held_us": 120.0, "irq_cpu_us": 150.0}  # what every legacy transaction stays within


@dataclass(frozen=True)
class Case:
    """One kind of transaction measured: `write` + repeated START + `read_len` bytes; `before` is
    sent (unmeasured) before each repeat, `setup` once before the first; `rejected`: the reply
    must carry ERROR (else it must not)."""

    name: str
    write: bytes
    read_len: int
    rejected: bool = False
    before: tuple[tuple[bytes, int], ...] = ()
    setup: tuple[tuple[bytes, int], ...] = ()


def legacy_transaction(name: str) -> tuple[bytes, int]:
    """(write, read_len) of register `name` as the original host uses it."""
    reg = P.register(name)
    if reg.writable:
        return bytes([reg.addr]) + reg.encode(*COMMAND_VALUES[name]), 1
    return bytes([reg.addr]), reg.rsize + 1


def _command(name: str, *values: Any) -> bytes:
    reg = P.register(name)
    return bytes([reg.addr]) + reg.encode(*values)


def _nan_rpm() -> bytes:
    return bytes([P.SETRPM]) + struct.pack("<f", float("nan"))


# Frames the joint rejects, one per way of being rejected that a host can provoke on an enabled
# joint (a full queue needs 16 commands within one loop iteration; a disabled joint, a bad
# configuration): name, write, read_len, setup (sent once before).
REJECTED: tuple[Case, ...] = (
    Case("reject.unknown_register", bytes([0x3F]), 1, True),
    Case("reject.outside_map", bytes([0xFF]), 1, True),
    # Short: kept open until the read (a STOP serviced late splits commands: the adapter's note);
    # [SETRPM] alone, a read of a command register, takes the same path.
    Case("reject.length", bytes([P.SETRPM, 0, 0]), 1, True),
    Case("reject.value", _command("SETCURRENT", 0)[:1] + bytes([101]), 1, True),
    Case("reject.not_finite", _nan_rpm(), 1, True),
    Case("reject.homing_sensitivity", _command("HOME", 1, 30, 0, 30), 1, True),
    # A HOME holds BUSY for at least its settling time (500 ms) whatever the motor does.
    Case("reject.busy", _command("CHECKORIENTATION", 10.0), 1, True,
         before=((_command("STOP", 0), 1), (_command("HOME", *COMMAND_VALUES["HOME"]), 1))),
    Case("reject.not_enabled", _command("SETRPM", 10.0), 1, True,
         setup=((_command("DISABLECLOSEDLOOP", 0), 1),)),
)


def register_cases() -> list[Case]:
    """Every register of the protocol map as a host uses it, then the reads of registers that are
    commands too, then REJECTED."""
    cases = []
    reads = []
    for reg in P.REGISTERS:
        if not reg.supported:
            cases.append(Case(reg.name, bytes([reg.addr]), 1, True))
            continue
        write, read_len = legacy_transaction(reg.name)
        before = tuple(legacy_transaction(name) for name in BEFORE_EACH.get(reg.name, ()))
        cases.append(Case(reg.name, write, read_len, before=before))
        if reg.writable and reg.rsize:
            reads.append(Case("read." + reg.name, bytes([reg.addr]), reg.rsize + 1))
    return cases + reads + list(REJECTED)


def wait_on_bus(bus: JointBusClient, address: int = ADDRESS, limit: int = 500) -> None:
    """Probe until the joint has booted and joined the bus (it ignores its address until then)."""
    for _ in range(limit):
        if bus.transfer(address, None, 0, gap_us=20_000).ack:
            return
    raise RuntimeError(f"the joint at 0x{address:02x} never joined the bus")


def transaction_figures(bus: JointBusClient, write: bytes, read_len: int, *, repeats: int = REPEATS,
                        address: int = ADDRESS, before: Sequence[tuple[bytes, int]] = ()
                        ) -> tuple[float, float, list[Transaction]]:
    """Median SCL held and IRQ CPU time (us) of one transaction repeated `repeats` times, isolated,
    each PHASE_STEP_US later in the joint's main loop than the one before; `before` is sent
    (unmeasured) ahead of each."""
    done = []
    for i in range(repeats):
        for frame, length in before:
            bus.transfer(address, frame, length, gap_us=GAP_US)
        done.append(bus.transfer(address, write, read_len, gap_us=GAP_US + i * PHASE_STEP_US))
    held = statistics.median(t.scl_held_us for t in done)
    irq = statistics.median(t.irq_cpu_us or 0.0 for t in done)
    return held, irq, done


def wait_until_idle(bus: JointBusClient, address: int = ADDRESS, limit: int = 2000) -> None:
    """Poll PING until the joint's flags show no blocking task (the boot's orientation check)."""
    for _ in range(limit):
        t = bus.transfer(address, bytes([P.PING]), 2, gap_us=5000)
        if t.ack and not t.data[1] & P.FLAG_BUSY:
            return
    raise RuntimeError(f"the joint at 0x{address:02x} stayed BUSY")


def measure_case(bus: JointBusClient, case: Case) -> dict[str, float]:
    """The four figures of one case; RuntimeError if a reply's ERROR flag says it took another path."""
    for frame, length in case.setup:
        bus.transfer(ADDRESS, frame, length, gap_us=GAP_US)
    _, _, done = transaction_figures(bus, case.write, case.read_len, before=case.before)
    for t in done:
        flags = t.data[0 if case.rejected else case.read_len - 1] if t.ack else None
        if flags is None or bool(flags & P.FLAG_ERROR) != case.rejected:
            last = bus.transfer(ADDRESS, bytes([P.LASTERROR]), 5, gap_us=GAP_US).data
            raise RuntimeError(f"{case.name}: {t.write.hex()} answered {t.data.hex()} (ack {t.ack}), "
                               f"expected {'a rejection' if case.rejected else 'no ERROR'}; the last "
                               f"rejection: {P.reject_string(last[0])}, register 0x{last[1]:02x}")
    held = [t.scl_held_us for t in done]
    irq = [t.irq_cpu_us or 0.0 for t in done]
    return {"scl_held_us": statistics.median(held), "scl_held_us_max": max(held),
            "irq_cpu_us": statistics.median(irq), "irq_cpu_us_max": max(irq)}


def register_figures(bus: JointBusClient, cases: Sequence[Case] | None = None) -> dict[str, float]:
    """Every case of `cases` (register_cases()) on the enabled joint, each from the joint at rest
    and enabled (STOP, SETUP), then the worst of each figure (`chip.worst.*`, the cases named on
    stderr) and how many cases exceed LIMITS_US (`chip.over_limit.*`)."""
    wait_until_idle(bus)
    if not enable(bus):
        raise RuntimeError("the joint did not enable (are the device fakes on its pins?)")
    restore = [legacy_transaction("STOP"), legacy_transaction("SETUP")]
    figures: dict[str, float] = {}
    worst: dict[str, tuple[float, str]] = {}
    over: dict[str, int] = {}
    for case in cases if cases is not None else register_cases():
        for frame, length in restore:
            bus.transfer(ADDRESS, frame, length, gap_us=GAP_US)
        for figure, value in measure_case(bus, case).items():
            figures[f"chip.{figure}.{case.name}"] = round(value, 1)
            if value > worst.get(figure, (-1.0, ""))[0]:
                worst[figure] = (value, case.name)
            limit = LIMITS_US.get(figure.removesuffix("_max"))
            if figure.endswith("_max") and limit is not None:
                over[figure] = over.get(figure, 0) + (value > limit)
    for frame, length in restore:
        bus.transfer(ADDRESS, frame, length, gap_us=GAP_US)
    for figure, (value, name) in worst.items():
        figures[f"chip.worst.{figure}"] = round(value, 1)
        print(f"worst {figure}: {value:.1f} us, {name}", file=sys.stderr)
    for figure, count in over.items():
        figures[f"chip.over_limit.{figure}"] = count
    return figures


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
        figures.update(register_figures(bus))
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
