"""The serial debug console against a simulated joint's pseudo-terminal (real time)."""

from __future__ import annotations

import csv
import struct
import threading
import time
from collections.abc import Callable, Iterator

import pytest

from bioscara.transports import open_bus
from bioscara.cli import main
from bioscara.config import read_config
from bioscara.serial_console import CSV_HEADER, JointConsole, in_words, plot
from bioscara.firmware.spec import protocol as P
from bioscara.hardware import sim_joint_specs
from bioscara.joint import Joint
from bioscara.sim_server import Pty, SimServer


class Lines:
    """What the console printed, with a bounded wait for a line to turn up."""

    def __init__(self) -> None:
        self.lines: list[str] = []
        self._changed = threading.Condition()

    def __call__(self, line: str) -> None:
        with self._changed:
            self.lines.append(line)
            self._changed.notify_all()

    def wait_for(self, predicate: Callable[[str], bool], timeout: float = 2.0) -> str:
        def first_match() -> str | None:
            return next((line for line in self.lines if predicate(line)), None)

        with self._changed:
            found = self._changed.wait_for(first_match, timeout)
        assert found is not None, f"no such line within {timeout} s; got {self.lines}"
        return found


@pytest.fixture(scope="module")
def server() -> Iterator[SimServer]:
    config = read_config()
    with SimServer(sim_joint_specs(config), seed=config.sim.seed) as server:
        yield server


@pytest.fixture
def j1(server: SimServer) -> Iterator[Joint]:
    bus = open_bus(f"serial:{server.bridge_path}")
    joint = Joint("j1", 0x11, bus)
    joint.init()
    yield joint
    joint.disable()
    bus.close()


@pytest.fixture
def console(server: SimServer) -> Iterator[tuple[JointConsole, Lines]]:
    lines = Lines()
    console = JointConsole(server.joint_paths["J1"], on_line=lines)
    yield console, lines
    console.close()


def test_status_and_log_lines(console: tuple[JointConsole, Lines], j1: Joint) -> None:
    joint_console, lines = console
    joint_console.send("status")
    lines.wait_for(lambda line: line.startswith("J1 at 0x11") and "flags" in line)
    lines.wait_for(lambda line: line.startswith("stall  spike limit"))
    j1.bus.transfer(0x11, bytes([P.SETRPM]) + struct.pack("<f", float("nan")), 1)  # rejected: logged
    lines.wait_for(lambda line: line == "J1 WARN rejected a frame for register 0x11: value out of range or not "
                   "finite (reason %d)" % P.REJECT_VALUE)


def test_codes_the_joint_logs_by_number_are_said_in_words() -> None:
    """The board logs reject reasons and homing outcomes as numbers (it keeps no texts for its
    heap); the console a person reads says the words, as the joint's own log once did."""
    assert in_words("J1 WARN homing ended, not homed: outcome 7") == (
        "J1 WARN homing ended, not homed: encoder reports no magnet (or does not answer): homing refused (outcome 7)")
    assert in_words("J2 WARN rejected a frame for register 0x40: reason 1") == (
        "J2 WARN rejected a frame for register 0x40: unknown register (reason 1)")
    assert in_words("J1 WARN homing ended, not homed: outcome 99") == (
        "J1 WARN homing ended, not homed: unknown homing outcome 99 (outcome 99)")
    for line in ("J1 WARN homing ended, not homed: aborted by STOP", "J1 INFO homed", "0x31 LASTERROR reason 4"):
        assert in_words(line) == line


def test_the_trace_is_captured_to_csv_and_plotted(console: tuple[JointConsole, Lines], j1: Joint,
                                                  server: SimServer, tmp_path) -> None:
    joint_console, lines = console
    # The trace is the original detector's samples; the shipped J1 runs the tracking one.
    server.bus.joint_at(0x11).core.set_stall_detector("original")
    j1.enable(20, 20)
    j1.enable_stallguard(5)  # samples flow while stall detection runs
    capture = joint_console.start_capture(tmp_path / "trace.csv")
    lines.wait_for(lambda line: line.startswith("trace on: raw despiked filtered"))
    deadline = time.monotonic() + 3.0
    while capture.rows < 30 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert joint_console.stop_capture() is capture and capture.rows >= 30
    lines.wait_for(lambda line: line == "trace off")
    with open(capture.path, newline="") as f:
        rows = list(csv.reader(f))
    assert tuple(rows[0]) == CSV_HEADER == ("time_s", "raw", "despiked", "filtered", "speed", "set_speed",
                                            "threshold", "stall")
    values = [[float(v) for v in row] for row in rows[1:]]
    assert len(values) == capture.rows
    assert all(row[6] == 50.0 and row[7] == 0.0 for row in values), "threshold 5 x 10, no stall"
    times = [row[0] for row in values]
    assert times == sorted(times) and 0.15 < times[-1] - times[0] < 3.0, "about 100 samples per second"

    chart = plot(joint_console.samples(), width=70, height=12).plain.splitlines()
    assert len(chart) == 12 and chart[0].startswith("trace: ")
    assert "━ despiked" in chart[-1] and "━ filtered" in chart[-1] and "━ threshold 50" in chart[-1]
    assert any(ch != "⠀" and "\u2800" <= ch <= "\u28ff" for line in chart[1:-1] for ch in line)


def test_cli_sends_commands_and_prints_the_answers(server: SimServer, capsys) -> None:
    path = server.joint_paths["J2"]
    assert main(["console", path, "-c", "log debug", "-c", "status", "-c", ":plot filtered", "--duration", "0.3"]) == 0
    out = capsys.readouterr().out
    assert "log level DEBUG" in out and "J2 at 0x12" in out and "trace: 0 samples" in out
    assert main(["console", path, "-c", "log info", "--duration", "0"]) == 0
    assert main(["console", path, "-c", "frobnicate", "--duration", "0.3"]) == 1, "the joint said error"
    assert "error: unknown command 'frobnicate'" in capsys.readouterr().out


def test_missing_and_busy_ports_fail_with_one_line(server: SimServer, tmp_path, capsys) -> None:
    assert main(["console", str(tmp_path / "ttyACM9"), "-c", "status"]) == 1
    err = capsys.readouterr().err.strip()
    assert "does not exist" in err and len(err.splitlines()) == 1
    with JointConsole(server.joint_paths["J3"], on_line=Lines()):
        assert main(["console", server.joint_paths["J3"], "-c", "status"]) == 1
    err = capsys.readouterr().err.strip()
    assert "busy" in err and len(err.splitlines()) == 1
    assert main(["console", server.joint_paths["J3"], "--plot", "torque"]) == 2
    assert "no trace column torque" in capsys.readouterr().err


def test_reconnects_when_the_board_resets(tmp_path) -> None:
    """A board reset: its port disappears, then comes back (here a symlink to a new terminal)."""
    link = tmp_path / "ttyACM0"
    board = Pty()
    link.symlink_to(board.path)
    lines = Lines()
    console = JointConsole(str(link), on_line=lines, retry_s=0.02)
    try:
        console.send("trace on")
        board.write_line("J1 INFO J1 ready at 0x11")
        lines.wait_for(lambda line: line == "J1 INFO J1 ready at 0x11")
        board.close()
        link.unlink()
        lines.wait_for(lambda line: line.startswith("console: ") and "lost" in line)
        board = Pty()
        link.symlink_to(board.path)
        lines.wait_for(lambda line: line == f"console: reconnected to {link}")
        assert console.reconnects == 1
        received = bytearray(64)
        deadline = time.monotonic() + 2.0
        n = 0
        while b"trace on\n" not in bytes(received[:n]) and time.monotonic() < deadline:
            n += board.readinto(memoryview(received)[n:])
            time.sleep(0.01)
        assert b"trace on\n" in bytes(received[:n]), "the trace is turned back on after the reset"
        board.write_line("0.5\t0.5\t0.4\t0\t0\t50\t0")
        deadline = time.monotonic() + 2.0
        while not console.samples() and time.monotonic() < deadline:
            time.sleep(0.01)
        assert [s.values for s in console.samples()] == [(0.5, 0.5, 0.4, 0.0, 0.0, 50.0, 0.0)]
    finally:
        console.close()
        board.close()
