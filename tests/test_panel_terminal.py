"""`bioscara panel` as a user runs it: a real process in a pseudo-terminal, driven by key presses.

Textual's pilot delivers keys to the app directly; only a real terminal shows which widget has the
focus when the panel starts, and so whether its keys reach the panel's bindings (an input field
focused first took `q` as text, and the panel did not quit). Each step waits on what the screen
shows, within a timeout.
"""

from __future__ import annotations

import asyncio
import errno
import os
import re
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from textual.drivers._writer_thread import WriterThread

from bioscara import interruption
from bioscara.panel.terminal import HangupSafeOutput, PanelDriver
from sim_session import quick_config, state_dir  # noqa: F401 (a fixture)
from tests.user_programs import TIMEOUT_S, Terminal, bioscara, position, stays


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


# SIGINT from `kill`; the Ctrl-C key reaches the panel as a key (its terminal is raw), and does the same
@pytest.mark.parametrize("ending", ["SIGTERM", "SIGINT", "Ctrl-C key", "closed terminal"])
def test_a_signal_or_a_closed_terminal_stops_the_joint_the_panel_moves(state_dir: Path, tmp_path: Path,
                                                                      ending: str) -> None:
    """The panel on the shared simulated arm sends j1 across its range; a signal (`kill`, a
    supervisor), Ctrl-C typed in it or the terminal's window closing ends the panel mid-way. The joint stops before
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
        sent = len(panel.shown)  # j1's row as shown before the go-to is no evidence that it moves
        panel.press("2.5\r", r"j1 to 2\.5: done")
        deadline = time.monotonic() + TIMEOUT_S
        while not [float(x) for x in J1_SHOWN.findall(panel.shown[sent:]) if float(x) > start + 0.5]:
            assert time.monotonic() < deadline, panel.shown[-3000:]
            panel.read()
        since = len(panel.shown)
        if ending == "closed terminal":
            assert panel.close_window() == 128 + signal.SIGHUP
        else:
            if ending == "Ctrl-C key":
                signum = signal.SIGINT
                os.write(panel.fd, b"\x03")
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


class HungUpTerminal:
    """A terminal whose window closed: every write and flush fails with EIO."""

    def write(self, text: str) -> int:
        raise OSError(errno.EIO, "Input/output error")

    flush = write

    def fileno(self) -> int:
        return 2

    def isatty(self) -> bool:
        return True


def test_the_panels_output_outlives_its_terminal() -> None:
    """Textual's writer thread ended on the first refused write; every write after the queue's 30
    then waited for good, and the panel hung in its shutdown instead of stopping its joint."""
    writer = WriterThread(HangupSafeOutput(HungUpTerminal()))  # type: ignore[arg-type]
    writer.start()

    def frames_then_shutdown() -> None:
        for _ in range(100):
            writer.write("frame")
        writer.stop()

    app = threading.Thread(target=frames_then_shutdown, daemon=True)
    app.start()
    app.join(TIMEOUT_S)
    assert not app.is_alive() and not writer.is_alive(), "the writes after the terminal went away blocked"


def test_sigcont_resumes_the_panel_only_after_a_suspend(monkeypatch: pytest.MonkeyPatch) -> None:
    """The kernel sends SIGCONT with SIGHUP when the terminal closes: Textual started its screen
    again then, a second writer and input thread on the dead terminal."""
    async def made() -> PanelDriver:
        return PanelDriver(object())  # type: ignore[arg-type]  (a driver is made in the app's loop)

    handlers = {signum: signal.getsignal(signum) for signum in (signal.SIGTSTP, signal.SIGCONT)}
    try:
        driver = asyncio.run(made())
        resumed: list[bool] = []
        monkeypatch.setattr(driver, "start_application_mode", lambda: resumed.append(True))
        monkeypatch.setattr(driver, "suspend_application_mode", lambda: None)
        monkeypatch.setattr(os, "kill", lambda pid, signum: None)  # SIGSTOP: the process stays
        signal.getsignal(signal.SIGCONT)(signal.SIGCONT, None)
        assert resumed == [], "resumed though never suspended"
        signal.getsignal(signal.SIGTSTP)(signal.SIGTSTP, None)
        signal.getsignal(signal.SIGCONT)(signal.SIGCONT, None)
        assert resumed == [True]
    finally:
        for signum, handler in handlers.items():
            signal.signal(signum, handler)
