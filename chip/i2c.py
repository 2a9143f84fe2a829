"""The emulated joint bus from Python: transactions against a board's I2C0 target, timed on the chip.

`JOINT_BUS` is the harness plugin (chip/src/joint_bus.mjs) that puts a bit-timed I2C controller on
a board's I2C0; `JointBusClient` runs transactions through the control channel and returns what the
chip did (reply bytes, SCL held by the target, the whole transaction, the target's I2C interrupt
CPU time). `ChipBus` is a `bioscara.bus.Bus` over it, so the host package's `Joint` and
communicator talk to the emulated joint unmodified.

    with EmulatedPico(image, plugins=[joint_bus_plugin(khz=400)]) as pico:
        bus = JointBusClient(pico)
        t = bus.transfer(0x11, b"\\x0f", 2)
        print(t.data, t.scl_held_us, t.irq_cpu_us)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable

from bioscara.bus.base import Bus

from .board import EmulatedPico

JOINT_BUS_MODULE = "src/joint_bus.mjs"


def joint_bus_plugin(*, board: str | None = None, khz: int = 400, name: str = "i2c") -> dict[str, Any]:
    """The harness plugin entry for EmulatedPico(plugins=[...]): a controller on `board`'s I2C0."""
    options: dict[str, Any] = {"khz": khz, "name": name}
    if board is not None:
        options["board"] = board
    return {"module": JOINT_BUS_MODULE, "options": options}


@dataclass(frozen=True)
class Transaction:
    """One transaction on the emulated bus, as the chip timed it (emulated microseconds)."""

    addr: int
    write: bytes
    read_len: int
    ack: bool  # False: the address or a written byte was NAKed (STOP followed), or timed out
    timed_out: bool  # the target held SCL past the controller's stretch timeout (35 ms)
    data: bytes
    start_us: float
    total_us: float  # START to the end of STOP, stretching included
    scl_held_us: float  # SCL held low by the target
    wire_us: float  # the nominal wire time (design.md bit-time formula) at the bus clock
    bits: int
    irq_cpu_us: float | None  # the target CPU's time in its I2C IRQ handler for this transaction

    @classmethod
    def from_reply(cls, r: dict[str, Any]) -> Transaction:
        irq = r.get("irqNs")
        return cls(addr=r["addr"], write=bytes(r["write"]), read_len=r["read"], ack=r["ack"],
                   timed_out=bool(r.get("timedOut")),
                   data=bytes(r["data"]), start_us=r["startNs"] / 1e3, total_us=r["totalNs"] / 1e3,
                   scl_held_us=r["heldNs"] / 1e3, wire_us=r["wireNs"] / 1e3, bits=r["bits"],
                   irq_cpu_us=None if irq is None else irq / 1e3)


class JointBusClient:
    """Transactions on an EmulatedPico's joint bus (the plugin from `joint_bus_plugin`)."""

    def __init__(self, pico: EmulatedPico, name: str = "i2c") -> None:
        self.pico = pico
        self.name = name

    def _spec(self, addr: int, write: bytes | None, read_len: int, gap_us: float) -> dict[str, Any]:
        return {"addr": addr, "write": list(write or b""), "read": read_len, "gapNs": round(gap_us * 1e3)}

    def transfer(self, addr: int, write: bytes | None, read_len: int = 0, *, gap_us: float = 0.0,
                 timeout: float = 60.0) -> Transaction:
        """Write `write` (None or empty: none), repeated START, read `read_len` bytes, STOP;
        it starts `gap_us` emulated microseconds after the request arrives."""
        reply = self.pico.request(f"{self.name}.transfer", timeout=timeout,
                                  **self._spec(addr, write, read_len, gap_us))
        return Transaction.from_reply(reply)

    def schedule(self, items: Iterable[tuple[int, bytes | None, int]], *, repeat: int = 1,
                 period_us: float = 0.0, gap_us: float = 0.0, timeout: float = 120.0) -> list[Transaction]:
        """`items` (addr, write, read_len) back to back, `repeat` times; with `period_us` each
        repetition starts that long after the previous one started (a host cycling at a rate)."""
        specs = [self._spec(a, w, r, gap_us) for a, w, r in items]
        reply = self.pico.request(f"{self.name}.schedule", timeout=timeout, items=specs, repeat=repeat,
                                  periodNs=round(period_us * 1e3))
        return [Transaction.from_reply(r) for r in reply["results"]]

    def start_cycle(self, items: Iterable[tuple[int, bytes | None, int]], *, period_us: float,
                    repeat: int) -> None:
        """Like `schedule`, but returns at once: a host cycling in the background; `state()`
        counts its transactions (`cycling`: ended, failed)."""
        specs = [self._spec(a, w, r, 0.0) for a, w, r in items]
        self.pico.request(f"{self.name}.cycle", items=specs, repeat=repeat, periodNs=round(period_us * 1e3))

    def state(self) -> dict[str, Any]:
        """The controller's and the target's state (queue, SCL holds, FIFO levels, interrupts)."""
        return self.pico.request(f"{self.name}.state")

    def set_khz(self, khz: int) -> None:
        self.pico.request(f"{self.name}.config", khz=khz)


class ChipBus(Bus):
    """A `bioscara.bus.Bus` on the emulated joint bus: the host package drives the chip unmodified.

    Every transaction is recorded in `transactions` (with the chip's timing)."""

    scheme = "chip"

    def __init__(self, client: JointBusClient, *, attempts: int = 1, speed_hz: int = 400_000) -> None:
        super().__init__(attempts=attempts, speed_hz=speed_hz)
        self.client = client
        self.transactions: list[Transaction] = []
        client.set_khz(speed_hz // 1000)

    def _transfer_once(self, addr: int, write: bytes | None, read_len: int) -> bytes:
        t = self.client.transfer(addr, write, read_len)
        self.transactions.append(t)
        if not t.ack:
            raise OSError(121, "Remote I/O error")
        return t.data

    def _probe(self, addr: int) -> bool:
        return self.client.transfer(addr, None, 0).ack

    def describe(self) -> str:
        return f"chip:{self.client.pico.port()}"
