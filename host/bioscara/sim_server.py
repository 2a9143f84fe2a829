"""The simulated arm in real time behind pseudo-terminals (`bioscara sim --pty`).

One pseudo-terminal speaks the HIL bridge framing: the bridge firmware itself (`hil_bridge.bridge`)
serves it, with a `machine.I2C` stand-in over the simulated joint bus, so `serial:<path>` reaches
the simulated joints through exactly the code path a USB bridge board runs. Every joint also gets
a pseudo-terminal with its serial debug console (`firmware.console.debug`) and its log lines.

Scheduling: one thread owns the simulation. Each turn it runs every joint's main loop up to the
wall clock (at the chip's loop period, so the joints follow real time), serves what arrived (bridge
requests are executed on the simulated bus at once, advancing its clock by the wire time; debug
commands go to their joint's console), then waits at most a millisecond for input on any
pseudo-terminal or client socket. Output to a terminal nobody reads is dropped, never waited for.

At rest: while every joint rests (no task, no setpoint, the driver's ramp at 0; see `moving`),
only input can change anything, so the wait is `IDLE_TURN_S` instead. The simulation still runs
every tick up to the wall clock, in one batch per turn, and input ends the wait at once, so the
simulation has caught up before anything is served: time passes for the joints exactly as before
(timeouts included), only a console's log lines may come up to a turn late. With `idle_exit_s`, a
server that is also without clients (`busy()`) and without input that long stops by itself.
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
from .firmware.core.clock import MonotonicClock
from .firmware.console.debug import DebugConsole
from .firmware.sim.bus import SimJointBus
from .firmware.sim.clock import VirtualClock
from .hil_bridge.bridge import Bridge

log = logging.getLogger("bioscara.sim_server")

_TURN_S = 0.001  # longest wait for input: one simulated main-loop tick
IDLE_TURN_S = 0.25  # longest wait for input while idle
_MAX_CATCH_UP_US = 20_000  # beyond the turn's wait; below the joints' 50 ms deadman
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

    def write_line(self, line: str | bytes | bytearray | memoryview) -> None:
        """One console line: text, or the bytes of one (the trace's reused buffer)."""
        data = line.encode() if isinstance(line, str) else bytes(line)
        self.write(data + b"\r\n")  # as MicroPython's print on USB serial

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
    terminals. `idle_exit_s`: end `serve_forever` after that long idle (None: never).
    """

    def __init__(self, specs: Sequence[SimJointSpec], *, seed: int = 1, speed_hz: int = 400_000,
                 port: str = "rp2", idle_exit_s: float | None = None) -> None:
        self.idle_exit_s = idle_exit_s
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
        """Serve `frontend` in the loop too: its `fds()` are waited on, its `poll()` runs every turn,
        and while its `busy()` (a client is connected) the server is not idle."""
        self._frontends.append(frontend)

    def request_stop(self) -> None:
        """End `serve_forever` after the current turn (from the loop's own thread, or any other)."""
        self._stop.set()

    def serve_forever(self) -> None:
        """Follow the wall clock and serve the terminals until `stop()` (or KeyboardInterrupt)."""
        pty_fds = [pty.fileno() for pty in self._ptys]
        wall_start = time.monotonic()
        sim_start = self.clock.now_us
        wait = waited = _TURN_S
        idle_since: float | None = None
        while not self._stop.is_set():
            wall = time.monotonic()
            target = sim_start + int((wall - wall_start) * 1e6)
            behind = target - self.clock.now_us
            allowed = int(waited * 1e6) + _MAX_CATCH_UP_US
            if behind > allowed:
                # This process was held up, or cannot simulate as fast as time passes (a loaded
                # machine): let simulated time slip rather than replay the pause as silence on the
                # bus, which the joints' deadman would take for a lost host, and rather than make
                # every request wait for a catch-up longer than the last one.
                sim_start -= behind - allowed
                target = self.clock.now_us + allowed
            if wait > _TURN_S:  # idle: nobody waited on an answer meanwhile, one batch
                self.bus.run_until(target)
            while self.clock.now_us < target:  # in slices, serving requests in between: answers stay prompt
                self.bus.run_until(min(target, self.clock.now_us + _SLICE_US))
                self._serve()
            self._serve()
            waiting_since = time.monotonic()  # the time spent waiting for input is what the joints rested
            fds = pty_fds + [fd for f in self._frontends for fd in f.fds()]
            if self.moving():
                wait, idle_since = _TURN_S, None
                select.select(fds, [], [], wait)
                waited = min(time.monotonic() - waiting_since, wait)
                continue
            wait = IDLE_TURN_S  # every joint rests: only input can change that, and input ends the wait
            if any(frontend.busy() for frontend in self._frontends):
                idle_since = None
            elif idle_since is None:
                idle_since = wall
            elif self.idle_exit_s is not None and wall - idle_since >= self.idle_exit_s:
                log.info("idle for %.0f s (no client, no joint moving): stopping", wall - idle_since)
                return
            if select.select(fds, [], [], wait)[0]:
                idle_since = None  # input on a terminal or the socket: somebody uses the arm
            waited = min(time.monotonic() - waiting_since, wait)

    def idle(self) -> bool:
        """No frontend has a client and no joint moves (see `moving`)."""
        return not any(frontend.busy() for frontend in self._frontends) and not self.moving()

    def moving(self) -> list[str]:
        """The joints (J1..J4) not at rest: a task running (homing...), a setpoint, or the ramp turning."""
        return [joint.cfg.joint for joint in self.bus.joints
                if joint.core.task_name is not None or joint.core.qd_set or joint.core.positioning
                or joint.stepper.driver_rpm()]

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
