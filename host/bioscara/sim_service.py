"""The shared simulated arm: one background process that every `sim:` bus of this user reaches.

A real bus keeps its state between commands and serves many processes at once (the kernel
serializes their transactions). The service does the same for the simulator: it runs the
simulated joints in real time (`sim_server.SimServer`, the same loop as `bioscara sim --pty`) and
serves transactions from any number of clients over a unix socket in the state directory, one at a
time in arrival order, in the thread that runs the joints. Its joint debug consoles and a HIL
bridge are on pseudo-terminals too (`bioscara sim` lists them).

It goes away by itself after `idle_exit_s` with no client connected and no joint moving
(`[sim] idle_exit_min`, 15 min by default; `bioscara sim start --idle-exit MIN`), so a service that
an aborted script or test run left behind does not linger; a client that stays connected (a
monitor, a shell, a panel) or a joint that still moves keeps it running.

Files in the state directory (0700): `sim.sock` (0600), `sim.lock` (held by the running service,
so two starts never run two arms and a crashed service leaves nothing that blocks the next one),
`sim.log` (what the service says).

The protocol: every message is a 4-byte little-endian length, then the body. A request body is an
op code and its payload; a reply body is a status and its payload.

    HELLO   JSON {"specs": [...]}     -> OK JSON status (or FAIL: another arm runs)
    XFER    addr, read_len, has_write, write bytes -> OK read bytes | NACK
    SCAN                              -> OK addresses
    STATUS                            -> OK JSON status
    STOP                              -> OK; the service ends
    CONFIG_READ   addr                -> OK the joint's configuration file | FAIL why
    CONFIG_WRITE  addr, file bytes    -> OK (read at the joint's next boot) | FAIL why (nothing changed)
    REBOOT        addr                -> OK (the joint's firmware restarts) | FAIL why
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import logging
import os
import socket
import stat
import struct
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

from .bus.base import Bus
from .bus.sim import SimJointSpec
from .errors import CommError, ConfigError
from .paths import private_dir

log = logging.getLogger("bioscara.sim_service")

SOCKET_NAME, LOCK_NAME, LOG_NAME = "sim.sock", "sim.lock", "sim.log"
HELLO, XFER, SCAN, STATUS, STOP, CONFIG_READ, CONFIG_WRITE, REBOOT = 1, 2, 3, 4, 5, 6, 7, 8
OK, NACK, FAIL = 0, 1, 2
MAX_MESSAGE = 64 * 1024  # a longer length prefix is a client that does not speak this protocol
START_TIMEOUT_S = 10.0  # for a new service to listen
REPLY_TIMEOUT_S = 2.0  # per request; the service answers within a millisecond or so when healthy
DEFAULT_IDLE_EXIT_S = 15 * 60.0
_LENGTH = struct.Struct("<I")


def specs_to_json(specs: Sequence[SimJointSpec]) -> list[dict[str, Any]]:
    return [asdict(spec) for spec in specs]


def socket_path(state_dir: Path) -> Path:
    path = state_dir / SOCKET_NAME
    if len(os.fsencode(path)) >= 100:  # sun_path holds 108 bytes on Linux, 104 on macOS
        raise ConfigError(f"the state directory {state_dir} is too long a path for the simulator's socket; "
                          "set XDG_STATE_HOME to a shorter directory")
    return path


def _private_file(path: Path, mode: str) -> Any:
    """`open(path, mode)` for appending, creating the file 0600."""
    return os.fdopen(os.open(path, os.O_RDWR | os.O_CREAT | os.O_APPEND, 0o600), mode)


# ---- the service ----


class _Client:
    """One connected client: bytes received but not yet served."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self.inbox = bytearray()


def _hung_up(sock: socket.socket) -> bool:
    """The peer closed its end (a received request may still be unread in our buffer)."""
    try:
        return sock.recv(1, socket.MSG_PEEK) == b""
    except (BlockingIOError, InterruptedError):
        return False
    except OSError:
        return True


class SocketFrontend:
    """Serves the unix socket from inside `SimServer`'s loop: `fds()` to wait on, `poll()` to serve."""

    def __init__(self, server: Any, listener: socket.socket, status: dict[str, Any]) -> None:
        self.server = server
        self.listener = listener
        self.status = status
        self.clients: dict[int, _Client] = {}
        self.served = 0

    def fds(self) -> list[int]:
        return [self.listener.fileno(), *self.clients]

    def busy(self) -> bool:
        """A client is connected (the server is not idle while one is)."""
        return bool(self.clients)

    def poll(self) -> None:
        self._accept()
        for fd, client in list(self.clients.items()):
            try:
                data = client.sock.recv(MAX_MESSAGE)
            except (BlockingIOError, InterruptedError):
                continue
            except OSError:
                data = b""
            if not data:
                self._drop(fd)
                continue
            client.inbox += data
            if not self._serve(client):
                self._drop(fd)

    def _accept(self) -> None:
        while True:
            try:
                sock, _ = self.listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            sock.setblocking(False)
            self.clients[sock.fileno()] = _Client(sock)

    def _serve(self, client: _Client) -> bool:
        """Answer every whole request received; False to hang up on a client that broke the protocol."""
        box = client.inbox
        while len(box) >= _LENGTH.size:
            (size,) = _LENGTH.unpack_from(box)
            if not 1 <= size <= MAX_MESSAGE:
                return False
            if len(box) < _LENGTH.size + size:
                return True
            if _hung_up(client.sock):
                return False  # the client gave up waiting (its timeout): a late answer would apply a command it reported as failed
            body = bytes(box[_LENGTH.size:_LENGTH.size + size])
            del box[:_LENGTH.size + size]
            status, payload = self._answer(body)
            reply = _LENGTH.pack(1 + len(payload)) + bytes((status,)) + payload
            try:
                client.sock.sendall(reply) if len(reply) < 4096 else client.sock.send(reply)
            except OSError:  # a client that does not read its answers is not waited for
                return False
        return True

    def _answer(self, body: bytes) -> tuple[int, bytes]:
        op, payload = body[0], body[1:]
        bus = self.server.bus
        self.served += 1
        if op == XFER and len(payload) >= 3:
            addr, read_len, has_write = payload[0], payload[1], payload[2]
            try:
                return OK, bytes(bus.transfer(addr, payload[3:] if has_write else None, read_len))
            except OSError as exc:
                return NACK, str(exc).encode()
        if op == SCAN:
            return OK, bytes(bus.scan())
        if op in (HELLO, STATUS):
            status = dict(self.status, clients=len(self.clients), transactions=self.served,
                          moving=[name.lower() for name in self.server.moving()],
                          uptime_s=round(time.monotonic() - self.status["started"], 3))
            if op == HELLO:
                try:
                    wanted = json.loads(payload)["specs"]
                except (ValueError, KeyError, TypeError):
                    return FAIL, b"a HELLO needs a JSON object with the joint specs"
                if wanted != self.status["specs"]:
                    return FAIL, json.dumps(status).encode()
            return OK, json.dumps(status).encode()
        if op == STOP:
            self.server.request_stop()
            return OK, b""
        if op in (CONFIG_READ, CONFIG_WRITE, REBOOT) and payload:
            return self._joint_file(op, bus.joint_at(payload[0]), payload[1:])
        return FAIL, f"unknown request {op}".encode()

    def _joint_file(self, op: int, joint: Any, data: bytes) -> tuple[int, bytes]:
        if joint is None:
            return FAIL, b"no simulated joint at that address"
        try:
            if op == CONFIG_READ:
                return OK, joint.config_file()
            if op == CONFIG_WRITE:
                joint.write_config_file(data)
            else:
                joint.power_cycle()
        except (OSError, ValueError) as exc:
            return FAIL, str(exc).encode()
        return OK, b""

    def close(self) -> None:
        for fd in list(self.clients):
            self._drop(fd)

    def _drop(self, fd: int) -> None:
        client = self.clients.pop(fd)
        with contextlib.suppress(OSError):
            client.sock.close()


def _not_a_socket(path: Path) -> str:
    """Why the service cannot listen at `path` ("" if nothing, or an old socket, is there)."""
    try:
        mode = path.lstat().st_mode
    except FileNotFoundError:
        return ""
    if stat.S_ISSOCK(mode):
        return ""
    kind = "directory" if stat.S_ISDIR(mode) else "symbolic link" if stat.S_ISLNK(mode) else "file"
    return f"{path} is a {kind}, not the simulated arm's socket: remove it (nothing else may use that name)"


def serve(state_dir: Path, specs: Sequence[SimJointSpec], *, seed: int = 1, speed_hz: int = 400_000,
          idle_exit_s: float | None = DEFAULT_IDLE_EXIT_S, ready: Any = None) -> int:
    """Run the service until STOP (or SIGTERM/SIGINT, or `idle_exit_s` idle; None: never); 0 also
    when another one already runs.

    `ready(line)` is told "ready" once clients can connect, or "running" if another service has
    the lock (that one serves).
    """
    from .sim_server import SimServer

    state_dir = private_dir(state_dir)
    path = socket_path(state_dir)
    lock = _private_file(state_dir / LOCK_NAME, "a+")
    try:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            if ready:
                ready("running")
            return 0
        in_the_way = _not_a_socket(path)
        if in_the_way:
            log.error("%s", in_the_way)
            if ready:
                ready(f"error: {in_the_way}")
            return 1
        with contextlib.suppress(FileNotFoundError):
            path.unlink()  # left by a service that crashed: we hold the lock, nobody else serves it
        listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        old = os.umask(0o177)
        try:
            listener.bind(os.fspath(path))
        finally:
            os.umask(old)
        listener.listen(16)
        listener.setblocking(False)
        server = SimServer(specs, seed=seed, speed_hz=speed_hz, idle_exit_s=idle_exit_s)
        status = {"pid": os.getpid(), "socket": os.fspath(path), "started": time.monotonic(),
                  "idle_exit_s": idle_exit_s,
                  "specs": specs_to_json(specs), "bridge": server.bridge_path, "consoles": server.joint_paths}
        frontend = SocketFrontend(server, listener, status)
        server.add_frontend(frontend)
        lock.seek(0)
        lock.truncate()
        lock.write(f"{os.getpid()}\n")
        lock.flush()
        log.info("simulated arm %s serving on %s (idle exit: %s)", ", ".join(s.firmware_joint.lower() for s in specs),
                 path, "never" if idle_exit_s is None else f"{idle_exit_s:g} s")
        if ready:
            ready("ready")
        try:
            server.serve_forever()
        except KeyboardInterrupt:
            pass
        finally:
            with contextlib.suppress(FileNotFoundError):
                path.unlink()  # first, so no new client connects to a service that is going
            frontend.close()
            listener.close()
            server.close()
            log.info("simulated arm stopped")
        return 0
    finally:
        lock.close()


def main(argv: list[str] | None = None) -> int:
    """`python -m bioscara.sim_service STATE_DIR SPECS_JSON SEED SPEED_HZ IDLE_EXIT_S`, as `start()`
    runs it (IDLE_EXIT_S "none": never)."""
    import signal

    state_dir, specs_json, seed, speed_hz, idle = (argv if argv is not None else sys.argv[1:])[:5]
    specs = [SimJointSpec(**spec) for spec in json.loads(specs_json)]
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")

    def stop(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, stop)

    def ready(line: str) -> None:
        print(line, flush=True)
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, 1)  # the starter has what it waited for; nothing more goes to its pipe
        os.close(devnull)

    return serve(Path(state_dir), specs, seed=int(seed), speed_hz=int(speed_hz),
                 idle_exit_s=None if idle == "none" else float(idle), ready=ready)


# ---- the client side ----


class _Connection:
    """One client connection: request, answer; OSError when the service is gone."""

    def __init__(self, path: Path, timeout: float = REPLY_TIMEOUT_S) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.sock.settimeout(timeout)
        try:
            self.sock.connect(os.fspath(path))
        except BaseException:
            self.sock.close()
            raise

    def ask(self, op: int, payload: bytes = b"") -> tuple[int, bytes]:
        self.sock.sendall(_LENGTH.pack(1 + len(payload)) + bytes((op,)) + payload)
        header = self._read(_LENGTH.size)
        (size,) = _LENGTH.unpack(header)
        if not 1 <= size <= MAX_MESSAGE:
            raise OSError(errno.EPROTO, "the simulator sent a malformed answer")
        body = self._read(size)
        return body[0], body[1:]

    def _read(self, n: int) -> bytes:
        data = bytearray()
        while len(data) < n:
            chunk = self.sock.recv(n - len(data))
            if not chunk:
                raise OSError(errno.ECONNRESET, "the simulator closed the connection")
            data += chunk
        return bytes(data)

    def close(self) -> None:
        self.sock.close()


def _connect(state_dir: Path) -> _Connection | None:
    """A connection to the running service, or None when none runs (no socket, or a stale one)."""
    try:
        return _Connection(socket_path(state_dir))
    except (FileNotFoundError, ConnectionRefusedError):
        return None
    except OSError as exc:
        raise CommError(f"cannot reach the simulated arm at {socket_path(state_dir)}: {exc.strerror or exc}") from None


def start(state_dir: Path, specs: Sequence[SimJointSpec], *, seed: int = 1, speed_hz: int = 400_000,
          idle_exit_s: float | None = DEFAULT_IDLE_EXIT_S, timeout: float = START_TIMEOUT_S) -> bool:
    """Start the service in the background unless it runs; True if this call started it.
    `idle_exit_s`: it ends after that long without a client and with every joint at rest (None: never).

    Concurrent starts are safe: the service that gets the lock serves, the others exit at once,
    and every caller waits (at most `timeout` s) until the socket answers.
    """
    state_dir = private_dir(state_dir)
    connection = _connect(state_dir)
    if connection is not None:
        connection.close()
        return False
    with _private_file(state_dir / LOG_NAME, "ab") as log_file:
        process = subprocess.Popen(
            [sys.executable, "-m", "bioscara.sim_service", os.fspath(state_dir),
             json.dumps(specs_to_json(specs)), str(seed), str(speed_hz),
             "none" if idle_exit_s is None else repr(float(idle_exit_s))],
            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=log_file, start_new_session=True)
    assert process.stdout is not None
    line = _read_line(process, timeout)
    process.stdout.close()
    if line == "ready":
        return True
    if line.startswith("error: "):
        process.wait()
        raise CommError(line.removeprefix("error: "))
    deadline = time.monotonic() + timeout
    if line == "running":  # another start won the lock: wait for it to listen
        while time.monotonic() < deadline:
            connection = _connect(state_dir)
            if connection is not None:
                connection.close()
                return False
            time.sleep(0.01)
    process.kill()
    raise CommError(f"the simulated arm did not start within {timeout:g} s; see {state_dir / LOG_NAME}")


def _read_line(process: subprocess.Popen[bytes], timeout: float) -> str:
    """The first line the new service prints, waiting at most `timeout` s ("" if none)."""
    import selectors

    assert process.stdout is not None
    with selectors.DefaultSelector() as selector:
        selector.register(process.stdout, selectors.EVENT_READ)
        if not selector.select(timeout):
            return ""
    return process.stdout.readline().decode(errors="replace").strip()


def status(state_dir: Path) -> dict[str, Any] | None:
    """What the running service reports (pid, socket, joints, terminals, uptime), or None."""
    connection = _connect(state_dir)
    if connection is None:
        return None
    try:
        code, payload = connection.ask(STATUS)
    except OSError:  # it is going away
        return None
    finally:
        connection.close()
    return json.loads(payload) if code == OK else None


def stop(state_dir: Path, timeout: float = START_TIMEOUT_S) -> bool:
    """Stop the running service and wait until it has let go of its lock; False if none ran."""
    connection = _connect(state_dir)
    if connection is None:
        return False
    try:
        connection.ask(STOP)
        connection.sock.settimeout(timeout)
        with contextlib.suppress(OSError):
            while connection.sock.recv(1):  # the service closes its connections as it ends
                pass
    finally:
        connection.close()
    with _private_file(state_dir / LOCK_NAME, "a+") as lock:
        _flock_within(lock, timeout)
    return True


def _flock_within(lock: Any, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while True:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return
        except OSError:
            if time.monotonic() > deadline:
                raise CommError(f"the simulated arm did not stop within {timeout:g} s") from None
            time.sleep(0.01)


class ServiceBus(Bus):
    """The `sim:` bus: the shared simulated arm, started on first use (`idle_exit_s`: see `start`).

    `specs` must match the running service's joints (else ConfigError: stop it first).
    """

    scheme = "sim"
    reaches_config_files = True

    def __init__(self, specs: Sequence[SimJointSpec], state_dir: Path, *, seed: int = 1,
                 autostart: bool = True, idle_exit_s: float | None = DEFAULT_IDLE_EXIT_S, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.state_dir = state_dir
        self.specs = list(specs)
        if autostart:
            start(state_dir, specs, seed=seed, speed_hz=self.speed_hz, idle_exit_s=idle_exit_s)
        self._connection: _Connection | None = None
        self.info = self._hello()

    def describe(self) -> str:
        return "sim:"

    def arm_lock_path(self) -> Path:
        return self.state_dir / "arm-sim.lock"  # beside the service: a private state dir has its own

    def _hello(self) -> dict[str, Any]:
        try:
            code, payload = self._ask(HELLO, json.dumps({"specs": specs_to_json(self.specs)}).encode())
        except OSError as exc:
            raise CommError(f"the simulated arm does not answer ({exc.strerror or exc}); see "
                            f"{self.state_dir / LOG_NAME}") from None
        info = json.loads(payload) if code in (OK, FAIL) and payload[:1] == b"{" else {}
        if code != OK:
            raise ConfigError("the simulated arm that runs has other joints than this configuration; "
                              "`bioscara sim stop` ends it (the next command starts one for this configuration)")
        return info

    def _ask(self, op: int, payload: bytes = b"") -> tuple[int, bytes]:
        with self._lock:
            reused = self._connection is not None
            try:
                return self._connected().ask(op, payload)
            except TimeoutError:
                self._disconnect()  # the service hears the hang-up and drops the request, unanswered
                raise
            except OSError:
                self._disconnect()
                if not reused:
                    raise
            except BaseException:
                self._disconnect()  # interrupted (Ctrl-C) mid-request: its answer must not reach the next one
                raise
            # The connection had gone stale (the service was restarted): one try on a fresh one.
            try:
                return self._connected().ask(op, payload)
            except BaseException:
                self._disconnect()
                raise

    def _connected(self) -> _Connection:
        if self._connection is None:
            connection = _connect(self.state_dir)
            if connection is None:
                raise OSError(errno.ENOTCONN, "the simulated arm is not running (`bioscara sim` starts it)")
            self._connection = connection
        return self._connection

    def _disconnect(self) -> None:
        if self._connection is not None:
            self._connection.close()
            self._connection = None

    def _transfer_once(self, addr: int, write: bytes | None, read_len: int) -> bytes:
        payload = bytes((addr, read_len, write is not None)) + (write or b"")
        code, data = self._ask(XFER, payload)
        if code == NACK:
            raise OSError(errno.EREMOTEIO, data.decode(errors="replace"))
        if code != OK:
            raise OSError(errno.EPROTO, data.decode(errors="replace"))
        return data

    def _probe(self, addr: int) -> bool:
        try:
            self._transfer_once(addr, b"", 0)
        except OSError as exc:
            if exc.errno == errno.EREMOTEIO:
                return False
            raise CommError(f"{self.describe()} {exc.strerror or exc}") from None
        return True

    def _joint_request(self, op: int, addr: int, data: bytes = b"") -> bytes:
        try:
            code, reply = self._ask(op, bytes((addr,)) + data)
        except OSError as exc:
            raise CommError(f"{self.describe()} {exc.strerror or exc}") from None
        if code != OK:
            raise ConfigError(f"the simulated joint at 0x{addr:02x}: {reply.decode(errors='replace')}")
        return reply

    def joint_config_file(self, addr: int) -> bytes:
        return self._joint_request(CONFIG_READ, addr)

    def write_joint_config_file(self, addr: int, data: bytes) -> None:
        self._joint_request(CONFIG_WRITE, addr, data)

    def reboot_joint(self, addr: int, timeout: float = 10.0) -> None:
        self._joint_request(REBOOT, addr)
        self._await_joint(addr, timeout)

    def scan(self, first: int = 0x08, last: int = 0x77) -> list[int]:
        try:
            code, data = self._ask(SCAN)
        except OSError as exc:
            raise CommError(f"{self.describe()} {exc.strerror or exc}") from None
        return [addr for addr in data if first <= addr <= last]

    def close(self) -> None:
        with self._lock:
            self._disconnect()
        super().close()


if __name__ == "__main__":
    sys.exit(main())
