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
from pathlib import Path

import pytest

from bioscara import interruption
from tests.doc_blocks import _ESCAPES
from tests.test_sim_service import quick_config, state_dir  # noqa: F401 (a fixture)
from tests.test_user_sessions import bioscara, position, stays

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


def session_members(sid: int) -> list[str]:
    """The processes still in session `sid` (what a terminal window's programs leave behind)."""
    members = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:  # it ended meanwhile
            continue
        if int(fields[3]) == sid and fields[0] != "Z":
            members.append(stat.parent.name)
    return members


J1_SHOWN = re.compile(r"▶ j1\s+([-+]\d+\.\d+) rad")
STOPPED = re.compile(r"stopped j1 at ([-+]\d+\.\d+) rad, j2 \(not homed\), j3 \(not homed\), j4 \(not homed\)\r?$",
                     re.M)


@pytest.mark.parametrize("ending", ["SIGTERM", "SIGINT", "closed terminal"])  # SIGINT from `kill`: a key press
# in the panel is a key (Ctrl-C there says how to quit)
def test_a_signal_or_a_closed_terminal_stops_the_joint_the_panel_moves(state_dir: Path, tmp_path: Path,
                                                                      ending: str) -> None:
    """The panel on the shared simulated arm sends j1 across its range; a signal (`kill`, a
    supervisor) or the terminal's window closing ends the panel mid-way. The joint stops before
    the panel exits, the panel says where, and nothing of it keeps running."""
    config = str(quick_config(tmp_path, watchdog_ms=1000))  # a loaded machine can stall the panel's cycle
    homed = bioscara("home", "j1", "--config", config)
    assert homed.returncode == 0, homed.stderr
    start, target = position(Path(config)), 2.5
    panel = Terminal("panel", "--config", config)
    try:
        panel.wait_for("Configure")
        panel.press("a", "configure: done")
        panel.press("a", "activate: done")
        panel.press("t", r"go to: type j1's target \(rad\), then Enter")
        panel.press("2.5\r", r"j1 to 2\.5: done")
        deadline = time.monotonic() + TIMEOUT_S
        while not [float(x) for x in J1_SHOWN.findall(panel.shown[-20000:]) if float(x) > start + 0.5]:
            assert time.monotonic() < deadline, panel.shown[-3000:]
            panel.read()
        since = len(panel.shown)
        if ending == "closed terminal":
            assert panel.close_window() == 128 + signal.SIGHUP
        else:
            signum = signal.Signals[ending]
            os.kill(panel.pid, signum)
            assert panel.wait_for_exit() == 128 + signum
            said = panel.shown[since:]
            assert f"interrupted ({interruption.CAUSES[signum]})" in said and "Traceback" not in said, said[-2000:]
            stopped = STOPPED.search(said)
            assert stopped is not None, said[-2000:]
            assert position(Path(config)) == pytest.approx(float(stopped.group(1)), abs=2e-3)
        assert session_members(panel.pid) == [], "a process of the panel outlived it"
        assert not (state_dir / "arm-sim.json").exists(), "it let go of the arm (commander.py)"
    finally:
        panel.close()
    where = position(Path(config))
    assert start + 0.5 < where < target - 0.1, f"j1 stopped mid-way, not at {where}"
    stays(Path(config), where)
