"""What the user-session tests share: `bioscara` run as a user runs it, a real process with
its output read line by line (bounded waits), or in a pseudo-terminal driven by key presses; where
the shared simulated arm's j1 stands."""

from __future__ import annotations

import contextlib
import json
import os
import pty
import re
import select
import selectors
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

from tests.doc_blocks import _ESCAPES

BIOSCARA = [sys.executable, "-m", "bioscara.cli"]
PROGRESS = re.compile(r"^j1 at ([-+][0-9.]+) rad, target ([-+][0-9.]+) rad")
STOPPED = re.compile(r"^stopped j1 at ([-+][0-9.]+) rad$", re.M)


def bioscara(*argv: str, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*BIOSCARA, *argv], capture_output=True, text=True, timeout=timeout)


@contextlib.contextmanager
def running(*argv: str) -> Iterator[subprocess.Popen[str]]:
    """`bioscara ARGV` in the background; killed at the end if a failed assertion left it running."""
    # SIGINT as a terminal delivers it, even when pytest runs as a background job (which ignores it)
    process = subprocess.Popen([*BIOSCARA, *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        yield process
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()


def wait_for_line(stream: object, pattern: re.Pattern[str], timeout: float) -> tuple[re.Match[str] | None, list[str]]:
    """Read lines until one matches `pattern` (None after `timeout` s or at the end of the stream)."""
    seen: list[str] = []
    deadline = time.monotonic() + timeout
    with selectors.DefaultSelector() as selector:
        selector.register(stream, selectors.EVENT_READ)  # type: ignore[arg-type]
        while time.monotonic() < deadline:
            if not selector.select(deadline - time.monotonic()):
                break
            line = stream.readline()  # type: ignore[attr-defined]
            if not line:
                break
            seen.append(line.rstrip("\n"))
            match = pattern.match(line)
            if match:
                return match, seen
    return None, seen


def position(config: Path) -> float:
    result = bioscara("info", "j1", "--json", "--config", str(config))
    assert result.returncode == 0, result.stderr
    return float(json.loads(result.stdout)["position"])


def stays(config: Path, where: float) -> None:
    """Where the command said j1 stopped is where it stays: no change over the next second of reads."""
    deadline = time.monotonic() + 1.0
    while time.monotonic() < deadline:
        assert abs(position(config) - where) < 2e-3


TIMEOUT_S = 30.0  # the panel starts in about 2 s on an idle machine; 2 cores shared by many runs
ARROW = {"right": b"\x1b[C", "left": b"\x1b[D", "escape": b"\x1b"}


class Terminal:
    """`bioscara ARGV` (by default the panel on the in-process simulator) in a pseudo-terminal 160
    columns wide, the leader of its own session as in a terminal window; `shown` is everything
    it wrote, escape sequences left out."""

    def __init__(self, *argv: str, lines: int = 50) -> None:
        self.pid, self.fd = pty.fork()
        if self.pid == 0:
            os.environ.update(COLUMNS="160", LINES=str(lines), TERM="xterm-256color")
            os.execv(sys.executable, [sys.executable, "-m", "bioscara.cli",
                                      *(argv or ("--bus", "sim:virtual", "panel"))])
        self.output = b""
        self.status: int | None = None

    @property
    def shown(self) -> str:
        return _ESCAPES.sub(b"", self.output).decode(errors="replace")

    def read(self) -> str:
        """What the program wrote so far (`shown`), after waiting at most 0.1 s for more."""
        if select.select([self.fd], [], [], 0.1)[0]:
            try:
                self.output += os.read(self.fd, 65536)
            except OSError:  # the panel ended: its side of the terminal is closed
                pass
        return self.shown

    def wait_for(self, pattern: str, since: int = 0) -> None:
        """Wait until `pattern` (a regular expression) is on the screen after `since` characters."""
        deadline = time.monotonic() + TIMEOUT_S
        while not re.search(pattern, self.shown[since:]):
            assert time.monotonic() < deadline, (pattern, self.shown[since:][-3000:])
            self.read()

    def press(self, key: str, then: str) -> None:
        """Press `key` and wait until the screen shows `then`."""
        since = len(self.shown)
        os.write(self.fd, ARROW.get(key, key.encode()))
        self.wait_for(then, since)

    def wait_for_exit(self) -> int:
        deadline = time.monotonic() + TIMEOUT_S
        while self.status is None:
            assert time.monotonic() < deadline, ("the panel did not end", self.shown[-3000:])
            self.read()
            done, status = os.waitpid(self.pid, os.WNOHANG)
            if done:
                self.status = os.waitstatus_to_exitcode(status)
        self.read()  # what it said as it ended
        return self.status

    def close_window(self) -> int:
        """Close the terminal, as its window closes: the kernel hangs the session up (SIGHUP to its
        leader); the exit status once the program has ended."""
        os.close(self.fd)
        self.fd = -1
        deadline = time.monotonic() + TIMEOUT_S
        while self.status is None:
            assert time.monotonic() < deadline, "the panel did not end when its terminal closed"
            done, status = os.waitpid(self.pid, os.WNOHANG)
            if done:
                self.status = os.waitstatus_to_exitcode(status)
            else:
                time.sleep(0.05)
        return self.status

    def close(self) -> None:
        if self.status is None:
            os.kill(self.pid, signal.SIGKILL)
            os.waitpid(self.pid, 0)
        if self.fd >= 0:
            os.close(self.fd)
