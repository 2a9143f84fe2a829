"""Emulated Raspberry Pi Picos for tests and benchmarks: a node process running chip/src/harness.mjs.

Each board's USB CDC is a pseudo-terminal (`EmulatedPico.port`), so anything that talks to a Pico
over USB (mpremote, `bioscara flash`, pyserial) talks to it unchanged. A JSON-lines control channel
to the harness reports emulated time, pauses and steps the boards, and stops them.

    with EmulatedPico(fs_image=path) as pico:
        print(pico.exec("print(1 + 1)"), pico.seconds())
"""

from __future__ import annotations

import contextlib
import errno
import itertools
import json
import os
import selectors
import socket
import subprocess
import threading
import tty
from dataclasses import dataclass, field
from pathlib import Path
from queue import Empty, Queue
from typing import Any

from .paths import CHIP_DIR, RUNTIMES, missing, rp2040_dir

HARNESS = CHIP_DIR / "src" / "harness.mjs"
PTY_BACKLOG = 1 << 20  # bytes kept for a pseudo-terminal nobody reads; older output is dropped


class ChipError(RuntimeError):
    """The emulated board could not start, or the harness refused or failed a request."""


@dataclass
class BoardSpec:
    """One emulated Pico: its name on the control channel, and what is in its flash."""

    name: str = "pico"
    # MicroPython: a littlefs image for flash offset 0xA0000; CircuitPython: CIRCUITPY, a FAT image
    # for 0x100000 (see chip.fsimage)
    fs_image: Path | None = None
    uf2: Path | None = None  # default: the runtime's stock UF2 in ../shared/rp2040
    runtime: str = "micropython"  # or "circuitpython"

    def config(self, usb_fd: int) -> dict[str, Any]:
        out: dict[str, Any] = {"name": self.name, "usbFd": usb_fd, "runtime": self.runtime}
        if self.fs_image is not None:
            out["fs"] = str(self.fs_image)
        if self.uf2 is not None:
            out["uf2"] = str(self.uf2)
        return out


@dataclass
class _Link:
    """A board's USB CDC: pty master <-> socket to the harness."""

    name: str
    master: int
    slave: int  # held open, so the pty never hangs up between users
    port: str
    sock: socket.socket
    backlog: bytearray = field(default_factory=bytearray)


class EmulatedPico:
    """Emulated Picos in one node process, stepped together in emulated time."""

    def __init__(self, fs_image: Path | None = None, *, runtime: str = "micropython",
                 boards: list[BoardSpec] | None = None,
                 plugins: list[dict[str, Any]] | None = None, quantum_ns: int = 10_000,
                 paused: bool = False, realtime: bool = True, startup_timeout: float = 30.0) -> None:
        """`runtime`: "micropython" or "circuitpython", the firmware of the one board `fs_image`
        describes (`boards` name each board's own); `paused`: start stopped (step with run_for);
        `realtime`: a free-running board never runs ahead of wall time (off: as fast as this
        machine allows, idle time included)."""
        if runtime not in RUNTIMES:
            raise ChipError(f"unknown runtime {runtime!r}: one of {', '.join(RUNTIMES)}")
        problem = missing(runtime)
        if problem:
            raise ChipError(problem)
        self.specs = boards or [BoardSpec(fs_image=fs_image, runtime=runtime)]
        self.plugins = plugins or []
        self.quantum_ns = quantum_ns
        self.paused = paused
        self.realtime = realtime
        self.startup_timeout = startup_timeout
        self.links: dict[str, _Link] = {}
        self.process: subprocess.Popen[bytes] | None = None
        self.stderr_lines: list[str] = []
        self._replies: dict[int, Queue[dict[str, Any]]] = {}
        self._events: Queue[dict[str, Any]] = Queue()
        self._ids = itertools.count(1)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []

    # ---- lifecycle ----

    def start(self) -> EmulatedPico:
        child_socks = []
        boards = []
        for spec in self.specs:
            mine, theirs = socket.socketpair()
            master, slave = os.openpty()
            tty.setraw(slave)  # no echo or line editing: the board's bytes pass as they are
            os.set_blocking(master, False)
            mine.setblocking(True)  # sendall waits while the harness is busy: no input is lost
            self.links[spec.name] = _Link(spec.name, master, slave, os.ttyname(slave), mine)
            child_socks.append(theirs)
            boards.append(spec.config(theirs.fileno()))  # pass_fds keeps the number in the child
        config = {"boards": boards, "plugins": self.plugins, "quantumNanos": self.quantum_ns,
                  "paused": self.paused, "realtime": self.realtime}
        env = dict(os.environ, BIOSCARA_RP2040=str(rp2040_dir()))
        self.process = subprocess.Popen(
            ["node", str(HARNESS), json.dumps(config)], cwd=CHIP_DIR, env=env,
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            pass_fds=[s.fileno() for s in child_socks])
        for s in child_socks:
            s.close()
        self._spawn(self._read_control)
        self._spawn(self._read_stderr)
        self._spawn(self._bridge)
        try:
            ready = self._events.get(timeout=self.startup_timeout)
        except Empty:
            self.close()
            raise ChipError(f"the emulated Pico did not start: {self.stderr_text() or 'no output'}") from None
        if ready.get("event") != "ready":
            self.close()
            raise ChipError(f"the emulated Pico did not start: {self.stderr_text() or ready}")
        return self

    def close(self) -> None:
        """Stops the harness and the bridge; the pseudo-terminals go away."""
        if self.process is not None and self.process.poll() is None:
            try:
                self.process.stdin.close()  # type: ignore[union-attr]
                self.process.wait(timeout=5)
            except (OSError, subprocess.TimeoutExpired):
                self.process.kill()
                self.process.wait()
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=5)
        for link in self.links.values():
            for fd in (link.master, link.slave):
                with contextlib.suppress(OSError):
                    os.close(fd)
            link.sock.close()
        self.links.clear()

    def __enter__(self) -> EmulatedPico:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---- what tests use ----

    def port(self, name: str | None = None) -> str:
        """The pseudo-terminal path of a board's USB CDC (the first board by default)."""
        return self.links[name or self.specs[0].name].port

    def request(self, cmd: str, timeout: float = 60.0, **args: Any) -> dict[str, Any]:
        """One control-channel request; ChipError if the harness refuses it."""
        if self.process is None or self.process.poll() is not None:
            raise ChipError(f"the emulated Pico is not running: {self.stderr_text()}")
        ident = next(self._ids)
        box: Queue[dict[str, Any]] = Queue()
        with self._lock:
            self._replies[ident] = box
            self.process.stdin.write(json.dumps({"id": ident, "cmd": cmd, **args}).encode() + b"\n")  # type: ignore[union-attr]
            self.process.stdin.flush()  # type: ignore[union-attr]
        try:
            reply = box.get(timeout=timeout)
        except Empty:
            raise ChipError(f"no reply to {cmd} within {timeout} s") from None
        finally:
            self._replies.pop(ident, None)
        if not reply.get("ok"):
            raise ChipError(f"{cmd}: {reply.get('error')}")
        return reply

    def seconds(self) -> float:
        """Emulated time since power-on, in seconds."""
        return float(self.request("time")["seconds"])

    def run_for(self, seconds: float) -> float:
        """Steps a paused world by `seconds` of emulated time; returns the emulated time after."""
        return float(self.request("run", nanos=round(seconds * 1e9), timeout=600)["seconds"])

    def pause(self) -> float:
        return float(self.request("pause")["seconds"])

    def resume(self) -> float:
        return float(self.request("resume")["seconds"])

    def exec(self, code: str, name: str | None = None, timeout: float = 60.0, soft_reset: bool = False) -> str:
        """Runs `code` in the board's raw REPL (mpremote's transport); returns its output.
        `soft_reset`: interrupt main.py and start from a fresh heap first, as mpremote does
        (MicroPython only)."""
        from mpremote.transport_serial import SerialTransport

        if self._spec(name).runtime == "circuitpython":
            if soft_reset:
                raise ChipError("soft_reset: CircuitPython reloads code.py instead")
            self._circuitpython_repl(name, timeout)
        transport = SerialTransport(self.port(name), baudrate=115200)
        try:
            transport.enter_raw_repl(soft_reset=soft_reset)
            out, error = transport.exec_raw(code, timeout=timeout)
            if error:
                raise ChipError(f"the board raised: {error.decode(errors='replace').strip()}")
            transport.exit_raw_repl()
        finally:
            transport.close()
        return out.decode(errors="replace")

    def _spec(self, name: str | None) -> BoardSpec:
        return next(spec for spec in self.specs if name in (None, spec.name))

    def _circuitpython_repl(self, name: str | None, timeout: float) -> None:
        """Interrupts code.py and takes CircuitPython to its REPL prompt. After Ctrl-C it waits for
        "any key to enter the REPL" and would swallow the Ctrl-A of mpremote's raw REPL request."""
        import serial

        import time

        console = serial.Serial(self.port(name), timeout=0.1)  # short reads: the deadline bounds it
        try:
            console.write(b"\x03")
            seen = b""
            pressed = False
            deadline = time.monotonic() + timeout
            while not seen.endswith(b">>> "):
                if time.monotonic() > deadline:
                    raise ChipError(f"CircuitPython gave no REPL prompt: {seen[-200:]!r}")
                seen += console.read(4096)
                if not pressed and b"any key to enter the REPL" in seen:
                    console.write(b"\r")
                    pressed = True
        finally:
            console.close()

    def fs_image(self, name: str | None = None) -> bytes:
        """The board's filesystem region of flash as it is now (read it with chip.fsimage.read_image,
        or read_fat_image for CircuitPython's CIRCUITPY)."""
        import base64

        return base64.b64decode(self.request("fs", board=name)["image"])

    def stderr_text(self) -> str:
        return "\n".join(self.stderr_lines[-20:])

    # ---- threads ----

    def _spawn(self, target: Any) -> None:
        thread = threading.Thread(target=target, daemon=True, name=f"chip-{target.__name__}")
        thread.start()
        self._threads.append(thread)

    def _read_control(self) -> None:
        assert self.process is not None and self.process.stdout is not None
        for raw in self.process.stdout:
            try:
                message = json.loads(raw)
            except ValueError:
                self.stderr_lines.append(raw.decode(errors="replace").rstrip())
                continue
            box = self._replies.get(message.get("id")) if "id" in message else None
            if box is not None:
                box.put(message)
            elif "event" in message:
                self._events.put(message)
        self._events.put({"event": "exit"})

    def _read_stderr(self) -> None:
        assert self.process is not None and self.process.stderr is not None
        for raw in self.process.stderr:
            self.stderr_lines.append(raw.decode(errors="replace").rstrip())

    def _bridge(self) -> None:
        """Copies bytes both ways between every pty master and its board's socket."""
        selector = selectors.DefaultSelector()
        for link in self.links.values():
            selector.register(link.master, selectors.EVENT_READ, (link, "pty"))
            selector.register(link.sock, selectors.EVENT_READ, (link, "usb"))
        while not self._stop.is_set():
            for key, _ in selector.select(timeout=0.05):
                link, side = key.data
                if side == "pty":
                    try:
                        data = os.read(link.master, 65536)
                    except (BlockingIOError, InterruptedError):
                        continue
                    except OSError as error:
                        if error.errno == errno.EIO:  # no one has the pty open: nothing to read
                            continue
                        raise
                    try:
                        link.sock.sendall(data)
                    except OSError:  # the harness has gone: what was typed goes nowhere
                        selector.unregister(link.master)
                    continue
                try:
                    data = link.sock.recv(65536)
                except OSError:  # the harness has gone
                    data = b""
                if not data:
                    selector.unregister(link.sock)
                    continue
                link.backlog += data
            for link in self.links.values():
                self._drain_backlog(link)
        selector.close()

    @staticmethod
    def _drain_backlog(link: _Link) -> None:
        while link.backlog:
            try:
                written = os.write(link.master, link.backlog[:4096])
            except BlockingIOError:
                break  # nobody reads the pty: keep the newest output only
            del link.backlog[:written]
        if len(link.backlog) > PTY_BACKLOG:
            del link.backlog[:-PTY_BACKLOG]
