"""The simulated arm in real time behind pseudo-terminals (`bioscara sim --pty`).

One pseudo-terminal speaks the HIL bridge framing: the bridge firmware itself (`hil_bridge.bridge`)
serves it, with a `machine.I2C` stand-in over the simulated joint bus, so `serial:<path>` reaches
the simulated joints through exactly the code path a USB bridge board runs. Every joint also gets
a pseudo-terminal with its serial debug console (`firmware.debug`) and its log lines.

Scheduling: one thread owns the simulation. Each turn it runs every joint's main loop up to the
wall clock (one iteration per simulated millisecond, so the joints follow real time), then waits
at most a millisecond for input on any pseudo-terminal, and serves what arrived: bridge requests
are executed on the simulated bus at once (advancing its clock by the wire time), debug commands
go to their joint's console. Output to a terminal nobody reads is dropped, never waited for.
"""

from __future__ import annotations

import logging
import os
import select
import threading
import time
import tty
from collections.abc import Sequence
from typing import Any

from .bus.sim import SimJointSpec, build_joint
from .firmware.clock import MonotonicClock
from .firmware.debug import DebugConsole
from .firmware.sim.bus import SimJointBus
from .firmware.sim.clock import VirtualClock
from .hil_bridge.bridge import Bridge

log = logging.getLogger("bioscara.sim_server")

_TURN_S = 0.001  # longest wait for input: one simulated main-loop tick
_MAX_CATCH_UP_US = 20_000  # per turn; below the joints' 50 ms deadman
_SLICE_US = 2_000  # simulated time between looks at the terminals and clients


class Pty:
    """A pseudo-terminal in raw mode; the server holds both ends, clients open `path`.

    Holding the client end too keeps the terminal alive between clients (no hang-up on the
    server's end when a client closes it).
    """

    def __init__(self) -> None:
        self._fd, self._client_fd = os.openpty()
        tty.setraw(self._client_fd)
        os.set_blocking(self._fd, False)
        self.path = os.ttyname(self._client_fd)
        self.dropped = 0  # bytes written while nobody read

    def fileno(self) -> int:
        return self._fd

    def readinto(self, buf: bytearray | memoryview) -> int:
        """What clients wrote, without waiting; 0 when nothing is there."""
        try:
            data = os.read(self._fd, len(buf))
        except (BlockingIOError, InterruptedError):
            return 0
        buf[:len(data)] = data
        return len(data)

    def write(self, data: bytes | bytearray | memoryview) -> None:
        view = memoryview(data)
        while view:
            try:
                view = view[os.write(self._fd, view):]
            except BlockingIOError:
                self.dropped += len(view)
                return

    def write_line(self, text: str) -> None:
        self.write(text.encode() + b"\r\n")  # as MicroPython's print on USB serial

    def close(self) -> None:
        for fd in (self._fd, self._client_fd):
            try:
                os.close(fd)
            except OSError:
                pass


class SimI2C:
    """`machine.I2C` over the simulated joint bus, as the bridge firmware calls it.

    A write without STOP is held and sent with the read that follows (write, repeated START,
    read: one SimJointBus transaction); an absent address raises the NACK at the write.
    """

    def __init__(self, bus: SimJointBus) -> None:
        self._bus = bus
        self._held: tuple[int, bytes] | None = None

    def writeto(self, addr: int, buf: Any, stop: bool = True) -> int:
        data = bytes(buf)
        self._held = None
        joint = self._bus.joint_at(addr)
        if stop or joint is None or not joint.online:
            self._bus.transfer(addr, data, 0)  # raises OSError (NACK) for an absent address
        else:
            self._held = (addr, data)
        return len(data)

    def readfrom_into(self, addr: int, buf: Any, stop: bool = True) -> None:
        held, self._held = self._held, None
        write = held[1] if held is not None and held[0] == addr else None
        buf[:] = self._bus.transfer(addr, write, len(buf))

    def scan(self) -> list[int]:
        return self._bus.scan()


class SimServer:
    """Simulated joints for `specs` (see `hardware.sim_joint_specs`) behind pseudo-terminals.

    `bridge_path` speaks the bridge framing; `joint_paths` maps J1..J4 to debug consoles.
    Run it with `serve_forever()` or in a thread with `start()`/`stop()`; `close()` releases the
    terminals.
    """

    def __init__(self, specs: Sequence[SimJointSpec], *, seed: int = 1, speed_hz: int = 400_000,
                 port: str = "rp2") -> None:
        self.clock = VirtualClock()
        self.bus = SimJointBus(self.clock, bus_hz=speed_hz)
        self._ptys: list[Pty] = []
        self._bridge_pty = self._pty()
        # No REPL escape: there is no REPL behind the pty, and a stray CR + Ctrl-C must not end it.
        self.bridge = Bridge(SimI2C(self.bus), self._bridge_pty, MonotonicClock(), speed_hz, repl_escape=False)
        self.joint_paths: dict[str, str] = {}
        self._consoles: list[DebugConsole] = []
        for i, spec in enumerate(specs):
            pty = self._pty()
            joint = build_joint(spec, self.clock, seed + i, port, pty.write_line)
            self.bus.add(joint)
            self._consoles.append(DebugConsole(joint.core, pty.readinto, pty.write_line))
            self.joint_paths[spec.firmware_joint] = pty.path
        self._frontends: list[Any] = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.error: BaseException | None = None
        self.bus.boot()  # in virtual time, so clients find the joints on the bus

    @property
    def bridge_path(self) -> str:
        return self._bridge_pty.path

    def _pty(self) -> Pty:
        pty = Pty()
        self._ptys.append(pty)
        return pty

    def add_frontend(self, frontend: Any) -> None:
        """Serve `frontend` in the loop too: its `fds()` are waited on, its `poll()` runs every turn."""
        self._frontends.append(frontend)

    def request_stop(self) -> None:
        """End `serve_forever` after the current turn (from the loop's own thread, or any other)."""
        self._stop.set()

    def serve_forever(self) -> None:
        """Follow the wall clock and serve the terminals until `stop()` (or KeyboardInterrupt)."""
        pty_fds = [pty.fileno() for pty in self._ptys]
        wall_start = time.monotonic()
        sim_start = self.clock.now_us
        while not self._stop.is_set():
            target = sim_start + int((time.monotonic() - wall_start) * 1e6)
            behind = target - self.clock.now_us
            if behind > _MAX_CATCH_UP_US:
                # This process was held up: let simulated time slip rather than replay the pause
                # as silence on the bus, which the joints' deadman would take for a lost host.
                sim_start -= behind - _MAX_CATCH_UP_US
                target = self.clock.now_us + _MAX_CATCH_UP_US
            while self.clock.now_us < target:  # in slices, serving requests in between: answers stay prompt
                self.bus.run_until(min(target, self.clock.now_us + _SLICE_US))
                self._serve()
            select.select(pty_fds + [fd for f in self._frontends for fd in f.fds()], [], [], _TURN_S)
            self._serve()

    def _serve(self) -> None:
        for frontend in self._frontends:
            frontend.poll()
        self.bridge.poll()
        for console in self._consoles:
            console.poll()

    def start(self) -> None:
        """Serve in a background thread."""
        self._thread = threading.Thread(target=self._run, name="bioscara-sim-server", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            self.serve_forever()
        except BaseException as exc:  # kept for stop() to re-raise in the caller's thread
            self.error = exc
            log.exception("simulator server failed")

    def stop(self) -> None:
        """End serving (the thread, if any); re-raises what ended it early."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        if self.error is not None:
            raise RuntimeError("the simulator server failed") from self.error

    def close(self) -> None:
        try:
            self.stop()
        finally:
            for pty in self._ptys:
                pty.close()

    def __enter__(self) -> SimServer:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
