"""`bioscara panel` as a user runs it: a real process in a pseudo-terminal, driven by key presses.

Textual's pilot delivers keys to the app directly; only a real terminal shows which widget has the
focus when the panel starts, and so whether its keys reach the panel's bindings (an input field
focused first took `q` as text, and the panel did not quit). Each step waits on what the screen
shows, within a timeout.
"""

from __future__ import annotations

import os
import pty
import re
import select
import signal
import sys
import time
from collections.abc import Iterator

import pytest

from tests.doc_blocks import _ESCAPES

TIMEOUT_S = 30.0  # the panel starts in about 2 s on an idle machine; 2 cores shared by many runs
ARROW = {"right": b"\x1b[C", "left": b"\x1b[D", "escape": b"\x1b"}


class Terminal:
    """`bioscara --bus sim:virtual panel` in a 160x50 pseudo-terminal; `shown` is everything it
    wrote, escape sequences left out."""

    def __init__(self) -> None:
        self.pid, self.fd = pty.fork()
        if self.pid == 0:
            os.environ.update(COLUMNS="160", LINES="50", TERM="xterm-256color")
            os.execv(sys.executable, [sys.executable, "-m", "bioscara.cli", "--bus", "sim:virtual", "panel"])
        self.output = b""
        self.status: int | None = None

    @property
    def shown(self) -> str:
        return _ESCAPES.sub(b"", self.output).decode(errors="replace")

    def _read(self) -> None:
        if select.select([self.fd], [], [], 0.1)[0]:
            try:
                self.output += os.read(self.fd, 65536)
            except OSError:  # the panel ended: its side of the terminal is closed
                pass

    def wait_for(self, pattern: str, since: int = 0) -> None:
        """Wait until `pattern` (a regular expression) is on the screen after `since` characters."""
        deadline = time.monotonic() + TIMEOUT_S
        while not re.search(pattern, self.shown[since:]):
            assert time.monotonic() < deadline, (pattern, self.shown[since:][-3000:])
            self._read()

    def press(self, key: str, then: str) -> None:
        """Press `key` and wait until the screen shows `then`."""
        since = len(self.shown)
        os.write(self.fd, ARROW.get(key, key.encode()))
        self.wait_for(then, since)

    def wait_for_exit(self) -> int:
        deadline = time.monotonic() + TIMEOUT_S
        while self.status is None:
            assert time.monotonic() < deadline, ("the panel did not end", self.shown[-3000:])
            self._read()
            done, status = os.waitpid(self.pid, os.WNOHANG)
            if done:
                self.status = os.waitstatus_to_exitcode(status)
        self._read()  # what it said as it ended
        return self.status

    def close(self) -> None:
        if self.status is None:
            os.kill(self.pid, signal.SIGKILL)
            os.waitpid(self.pid, 0)
        os.close(self.fd)


@pytest.fixture
def terminal(private_home: object) -> Iterator[Terminal]:
    panel = Terminal()
    try:
        panel.wait_for("Configure")
        yield panel
    finally:
        panel.close()


def test_q_quits_the_panel_as_it_starts(terminal: Terminal) -> None:
    os.write(terminal.fd, b"q")
    assert terminal.wait_for_exit() == 0
    assert "Traceback" not in terminal.shown


def test_every_advertised_key_works_from_the_first_focus_and_q_stops_the_arm(terminal: Terminal) -> None:
    terminal.press("a", "configure: done")
    terminal.press("a", "activate: done")
    terminal.press("g", "gripper configure: done|the configuration has no gripper")
    terminal.press("p", "position control on: ")  # refused until the joints are homed: the key acted
    terminal.press("3", "selected j3")
    terminal.press("right", "jog j3: not homed")
    terminal.press("1", "selected j1")
    terminal.press("left", "jog j1: not homed")
    terminal.press("h", "home control on: done")
    terminal.press("H", "home all: ")
    terminal.press("escape", "STOP: done")
    since = len(terminal.shown)
    os.write(terminal.fd, b"q")
    assert terminal.wait_for_exit() == 0
    said = terminal.shown[since:]
    assert "Traceback" not in said
    # As on Ctrl-C (docs/stopping-and-output.md): the arm this panel activated gets STOP and the
    # panel says where each joint stopped.
    assert re.search(r"stopped j1 \S.*, j2 \S.*, j3 \S.*, j4 \S", said), said[-2000:]
