"""Who commands the arm on a bus: one commander, any number of watchers, across processes.

A real bus is shared by every process that opens it (each opens /dev/i2c-1 on a Raspberry Pi); the
joints cannot tell two hosts apart. Two rules keep programs from faulting each other:

* **One commander per bus.** A program that enables, moves, homes or switches a joint's protocol
  first takes the bus's commander lock: `flock(LOCK_EX)` on `arm-<bus>.lock` in the state
  directory, held for the program's life and released by the kernel however it ends (kill -9
  included). Beside it, `arm-<bus>.json` (written atomically) names the holder: pid, command line,
  start time. A second commander is refused with that name (`ArmBusyError`), or with
  `take_over=True` (`--take-over`) sends the holder SIGTERM (a program stops its motion on it)
  and waits for the lock.
* **Watchers never disturb the link.** A program that only reads never switches a joint's
  protocol and never sends a v2 frame (which would move the joint's sequence under the
  commander). With no commander, it reads the legacy map directly, holding `LOCK_SH` for the
  length of one read (so no commander switches a joint to v2 under it). While a commander holds
  the bus, it reads what the commander last read instead: the commander serves its joints' latest
  state on `arm-<bus>.sock` (JSON, one object per connection, no bus I/O).

Everything here is per user (the state directory is 0700).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import logging
import os
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .errors import BioscaraError, CommError
from .paths import private_dir

log = logging.getLogger("bioscara.commander")

CLAIM_WAIT_S = 1.0  # for watchers' momentary shared locks to end
TAKE_OVER_WAIT_S = 10.0  # for a commander told to stop (SIGTERM) to let go
ASK_TIMEOUT_S = 0.5  # for the commander's published state


class ArmBusyError(BioscaraError):
    """Another program commands the arm on this bus."""


class CommanderLeft(CommError):
    """The commander a watcher asked let go of the arm meanwhile: watch again."""


@dataclass(frozen=True)
class Holder:
    """The program that commands the arm: its pid, command line and since when (Unix time)."""

    pid: int
    program: str
    since: float
    socket: str

    def describe(self) -> str:
        return f"pid {self.pid} ({self.program})"


def program_name() -> str:
    """This process's command line as a user typed it (`bioscara move j1 2`)."""
    argv = list(sys.argv) or ["python"]
    # `python -m bioscara.cli` runs the same command as the `bioscara` script
    argv[0] = "bioscara" if argv[0].endswith(os.path.join("bioscara", "cli.py")) else os.path.basename(argv[0])
    return " ".join(argv)[:200]


class Commander:
    """The commander lock of one bus (`lock_path`) as one process sees it.

    `claim()` makes this process the commander (re-entrant: every claim needs a `release()`);
    `watch()` is what a watcher does around each read. `publish(source)` registers a callable
    returning this process's joint states (a JSON-able dict), served to watchers while claimed.
    """

    def __init__(self, lock_path: Path, bus_name: str) -> None:
        self.lock_path = lock_path
        self.info_path = lock_path.with_suffix(".json")
        self.socket_path = lock_path.with_suffix(".sock")
        self.bus_name = bus_name
        self.take_over = False  # what `claim()` does when another program commands (--take-over)
        self._claims = 0
        self._fd: int | None = None
        self._sources: list[Callable[[], dict[str, Any]]] = []
        self._server: socket.socket | None = None
        self._mutex = threading.RLock()

    @property
    def claimed(self) -> bool:
        return self._claims > 0

    # ---- the commander ----

    def claim(self, take_over: bool | None = None) -> None:
        """Become the commander, or raise ArmBusyError naming the one that is (`take_over`, by
        default `self.take_over`: ask it to stop with SIGTERM and wait up to TAKE_OVER_WAIT_S
        for it to let go)."""
        if take_over is None:
            take_over = self.take_over
        with self._mutex:
            if self._claims:
                self._claims += 1
                return
            fd = os.open(self._ensure_dir() / self.lock_path.name, os.O_RDWR | os.O_CREAT, 0o600)
            try:
                self._lock(fd, take_over)
            except BaseException:
                os.close(fd)
                raise
            self._fd = fd
            self._claims = 1
            self._serve()
            _write_atomically(self.info_path, json.dumps(
                {"pid": os.getpid(), "program": program_name(), "since": time.time(),
                 "socket": os.fspath(self.socket_path)}))
            log.info("commanding the arm on %s", self.bus_name)

    def _lock(self, fd: int, take_over: bool) -> None:
        deadline = time.monotonic() + CLAIM_WAIT_S
        signalled: Holder | None = None
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                return
            except BlockingIOError:
                pass
            holder = self.holder()
            if holder is not None and signalled is None:
                if not take_over:
                    raise ArmBusyError(
                        f"the arm on {self.bus_name} is commanded by {holder.describe()} since "
                        f"{time.strftime('%H:%M:%S', time.localtime(holder.since))}; wait for it to end, "
                        "or take over with --take-over (it is stopped)")
                log.warning("taking over the arm from %s", holder.describe())
                with contextlib.suppress(ProcessLookupError):
                    os.kill(holder.pid, signal.SIGTERM)
                signalled = holder
                deadline = time.monotonic() + TAKE_OVER_WAIT_S
            if time.monotonic() > deadline:
                who = signalled.describe() if signalled else "programs reading the arm"
                raise ArmBusyError(f"{who} did not let go of the arm on {self.bus_name} "
                                   f"within {TAKE_OVER_WAIT_S if signalled else CLAIM_WAIT_S:g} s")
            time.sleep(0.005)

    def release(self) -> None:
        """Undo one `claim()`; the last one lets go of the lock."""
        with self._mutex:
            if not self._claims:
                return
            self._claims -= 1
            if self._claims:
                return
            if self._server is not None:
                with contextlib.suppress(OSError):
                    self._server.close()
                self._server = None
            with contextlib.suppress(FileNotFoundError):
                self.socket_path.unlink()
            with contextlib.suppress(FileNotFoundError):
                self.info_path.unlink()
            assert self._fd is not None
            os.close(self._fd)  # releases the lock
            self._fd = None
            self._sources.clear()

    def publish(self, source: Callable[[], dict[str, Any]]) -> None:
        """Serve `source()`'s joint states to watchers while this process commands."""
        with self._mutex:
            self._sources.append(source)

    def withdraw(self, source: Callable[[], dict[str, Any]]) -> None:
        with self._mutex:
            if source in self._sources:
                self._sources.remove(source)

    def _serve(self) -> None:
        with contextlib.suppress(FileNotFoundError):
            self.socket_path.unlink()  # a crashed commander's; we hold the lock now
        server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        old = os.umask(0o177)
        try:
            server.bind(os.fspath(self.socket_path))
        except OSError as exc:  # watchers then see no state; commanding works regardless
            server.close()
            log.warning("cannot serve the arm's state on %s: %s", self.socket_path, exc)
            return
        finally:
            os.umask(old)
        server.listen(8)
        self._server = server
        threading.Thread(target=self._answer_all, args=(server,), name="bioscara-commander", daemon=True).start()

    def _answer_all(self, server: socket.socket) -> None:
        while True:
            try:
                connection, _ = server.accept()
            except OSError:
                return  # closed by release()
            with connection:
                connection.settimeout(ASK_TIMEOUT_S)
                with contextlib.suppress(OSError):
                    connection.sendall(json.dumps(self.snapshot()).encode())

    def snapshot(self) -> dict[str, Any]:
        """What watchers get: this process, and every published joint's latest state."""
        joints: dict[str, Any] = {}
        with self._mutex:
            sources = list(self._sources)
        for source in sources:
            try:
                joints.update(source())
            except Exception as exc:  # a source mid-change: serve the others
                log.debug("state source failed: %s", exc)
        return {"pid": os.getpid(), "program": program_name(), "time": time.time(), "joints": joints}

    # ---- watchers ----

    def holder(self) -> Holder | None:
        """The program named as commander, if its record is there and it lives."""
        try:
            data = json.loads(self.info_path.read_text())
            holder = Holder(int(data["pid"]), str(data["program"]), float(data["since"]), str(data["socket"]))
        except (OSError, ValueError, KeyError, TypeError):
            return None
        try:
            os.kill(holder.pid, 0)
        except ProcessLookupError:
            return None
        except PermissionError:
            pass
        return holder

    @contextlib.contextmanager
    def watch(self) -> Iterator[Holder | None]:
        """Around one read of a watcher: None while no other program commands (the bus is free
        to read in the legacy map, and stays so until the block ends), else the commander, whose
        `published()` state stands in for the joints'."""
        if self._claims:  # this process commands: its own joints are read directly
            yield None
            return
        fd = os.open(self._ensure_dir() / self.lock_path.name, os.O_RDWR | os.O_CREAT, 0o600)
        try:
            holder = self._holder_or_shared_lock(fd)
            yield holder
        finally:
            os.close(fd)

    def _holder_or_shared_lock(self, fd: int) -> Holder | None:
        """None with the shared lock taken on `fd`, or the commander. A commander writes its
        record just after it takes the lock: wait for it (at most CLAIM_WAIT_S)."""
        deadline = time.monotonic() + CLAIM_WAIT_S
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
                return None
            except BlockingIOError:
                pass
            holder = self.holder()
            if holder is not None:
                return holder
            if time.monotonic() > deadline:
                return Holder(0, "a program starting to command", time.time(), "")
            time.sleep(0.005)

    def published(self, holder: Holder) -> dict[str, Any]:
        """The commander's latest joint states; CommanderLeft when it has let go since `watch()`
        named it, CommError when it commands but does not answer."""
        if not holder.socket:
            raise CommError(f"{holder.describe()} does not serve the arm's state yet")
        try:
            with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as connection:
                connection.settimeout(ASK_TIMEOUT_S)
                connection.connect(holder.socket)
                chunks = []
                while chunk := connection.recv(65536):
                    chunks.append(chunk)
            return dict(json.loads(b"".join(chunks)))
        except (OSError, ValueError) as exc:
            if self.holder() != holder:  # it ended between our look at the lock and the question
                raise CommanderLeft(f"{holder.describe()} let go of the arm") from None
            raise CommError(f"{holder.describe()} commands the arm and does not tell its state "
                            f"({getattr(exc, 'strerror', None) or exc})") from None

    def _ensure_dir(self) -> Path:
        return private_dir(self.lock_path.parent)


def _write_atomically(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.replace(tmp, path)


_COMMANDERS: dict[Path, Commander] = {}
_REGISTRY_LOCK = threading.Lock()


def commander_for(lock_path: Path, bus_name: str) -> Commander:
    """The one Commander of this process for `lock_path` (buses opened twice share it)."""
    with _REGISTRY_LOCK:
        commander = _COMMANDERS.get(lock_path)
        if commander is None:
            commander = _COMMANDERS[lock_path] = Commander(lock_path, bus_name)
        return commander
