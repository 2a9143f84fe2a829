"""A user's sessions with the shared simulated arm: real `bioscara` processes in real time,
signalled and piped as a person or a supervisor would. Each waits on what the process prints
(bounded), never on a guessed delay.
"""

from __future__ import annotations

import re
import signal
import subprocess
import time
from pathlib import Path

import pytest

from sim_session import quick_config, state_dir  # noqa: F401 (a fixture)
from tests.user_programs import (BIOSCARA, PROGRESS, STOPPED, Terminal, bioscara, position, running, stays,
                                 wait_for_line)


@pytest.mark.parametrize("signals", [(signal.SIGINT, signal.SIGTERM, signal.SIGHUP)])
def test_a_signal_stops_a_move_midway_and_says_where(state_dir: Path, tmp_path: Path,  # noqa: F811
                                                     signals: tuple[signal.Signals, ...]) -> None:
    config = str(quick_config(tmp_path))
    homed = bioscara("home", "j1", "--config", config)
    assert homed.returncode == 0, homed.stderr
    for signum in signals:
        start = position(Path(config))
        target = -2.5 if start > 0 else 2.5  # the far side: seconds of motion to interrupt
        with running("move", "j1", str(target), "--config", config) as move:
            # The progress lines (stderr, one every 0.5 s when not on a terminal) until j1 has gone 0.5 rad.
            moved = None
            seen: list[str] = []
            while moved is None:
                match, lines = wait_for_line(move.stderr, PROGRESS, 30.0)
                seen += lines
                assert match is not None, f"no progress line showing the move: {seen}"
                assert float(match.group(2)) == target
                if abs(float(match.group(1)) - start) >= 0.5:
                    moved = float(match.group(1))
            assert abs(moved - target) > 0.5, f"the move was over before it could be interrupted: {seen}"
            move.send_signal(signum)
            out, err = move.communicate(timeout=30)
        assert move.returncode == 128 + signum, (move.returncode, err)
        assert "Traceback" not in err
        stopped = STOPPED.search(err)
        assert stopped is not None, err
        where = float(stopped.group(1))
        assert abs(where - target) > 0.1, "the joint stopped short of the target"
        stays(Path(config), where)


def test_a_closed_terminal_stops_a_move_midway(state_dir: Path, tmp_path: Path) -> None:  # noqa: F811
    """`bioscara move` in a terminal window that closes (an SSH session that drops): the kernel
    hangs the session up; the progress drawn in place can no longer be written. The joint stops
    where it is, not at the target, and stays there."""

    config = str(quick_config(tmp_path, watchdog_ms=1000))  # a loaded machine can stall the move's cycle
    assert bioscara("home", "j1", "--config", config).returncode == 0
    start, target = position(Path(config)), 2.5
    move = Terminal("move", "j1", str(target), "--config", config)
    try:
        move.wait_for(rf"j1 at ([-+]\d\.\d+) rad, target \+2\.50000 rad")  # the progress, redrawn in place
        deadline = time.monotonic() + 30.0
        while not [x for x in re.findall(r"j1 at ([-+]\d\.\d+) rad", move.shown[-2000:]) if float(x) > start + 0.3]:
            assert time.monotonic() < deadline, move.shown[-2000:]
            move.read()
        assert move.close_window() == 128 + signal.SIGHUP
    finally:
        move.close()
    where = position(Path(config))
    assert start + 0.3 < where < target - 0.1, f"j1 stopped mid-way, not at {where}"
    stays(Path(config), where)


def pipe_into_head(lines: int, *argv: str) -> tuple[int, str, str]:
    """`bioscara ARGV | head -LINES`: bioscara's exit status and stderr, head's output."""
    producer = subprocess.Popen([*BIOSCARA, *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    head = subprocess.Popen(["head", f"-{lines}"], stdin=producer.stdout, stdout=subprocess.PIPE, text=True)
    assert producer.stdout is not None
    producer.stdout.close()  # head holds the pipe's only reading end: when it exits, the pipe is broken
    try:
        shown, _ = head.communicate(timeout=60)
        _, err = producer.communicate(timeout=60)
    finally:
        for process in (producer, head):
            if process.poll() is None:
                process.kill()
                process.wait()
    return producer.returncode, err, shown


def test_monitor_into_head_ends_quietly() -> None:
    status, err, shown = pipe_into_head(2, "monitor", "--bus", "sim:virtual")
    assert len(shown.splitlines()) == 2 and " rad/s " in shown
    assert status == 141 and err == "", err  # 128 + SIGPIPE, as `yes | head`; no traceback, no error


def test_console_into_head_ends_quietly_and_the_bridge_is_named(state_dir: Path) -> None:  # noqa: F811
    from bioscara import sim_service

    assert bioscara("sim", "start").returncode == 0
    status = sim_service.status(state_dir)
    assert status is not None
    code, err, shown = pipe_into_head(3, "console", status["consoles"]["J1"], "-c", "status", "-c", "regs",
                                      "--duration", "5")
    assert len(shown.splitlines()) == 3 and shown.startswith("J1 at 0x11")
    assert code == 141 and "Traceback" not in err and err == "", err
    bridge = bioscara("console", status["bridge"], "-c", "status")
    assert bridge.returncode == 1
    assert f"nothing answered on {status['bridge']}: it is not a joint's debug console" in bridge.stderr


def test_sigterm_stops_the_demo_midway_and_says_where() -> None:
    """The demo's arm (the in-process simulator here: BIOSCARA_BUS=sim:virtual) stops like `move`'s."""
    with running("demo") as demo:
        step, seen = wait_for_line(demo.stdout, re.compile(r"^  above pick: done"), 120.0)
        assert step is not None, seen
        demo.send_signal(signal.SIGTERM)
        _, err = demo.communicate(timeout=60)
    assert demo.returncode == 128 + signal.SIGTERM, err
    assert "interrupted (SIGTERM)" in err and "Traceback" not in err
    assert re.search(r"^stopped j1 at [-+]\d\.\d{5} rad, j2 at [-+]\d\.\d{5} m, j3 at .*, j4 at ", err, re.M), err


def test_a_directory_in_the_sockets_place_is_a_clear_error(state_dir: Path) -> None:  # noqa: F811
    (state_dir / "sim.sock").mkdir(parents=True)
    result = bioscara("scan")
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert f"{state_dir / 'sim.sock'} is a directory, not the simulated arm's socket: remove it" in result.stderr
    assert "Traceback" not in (state_dir / "sim.log").read_text()


class RecordingBus:
    def __init__(self) -> None:
        self.transfers: list[tuple[int, bytes | None, int]] = []

    def transfer(self, addr: int, write: bytes | None, read_len: int) -> bytes:
        self.transfers.append((addr, write, read_len))
        return bytes(read_len)


def test_the_service_drops_a_request_whose_client_gave_up(tmp_path: Path) -> None:
    """A client that timed out (it reported a CommError and hung up) must not see its command
    applied later, when the busy service reaches it (a -360 degree turn after the error)."""
    import socket
    from types import SimpleNamespace

    from bioscara import sim_service

    path = tmp_path / "s.sock"
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(str(path))
    listener.listen(4)
    listener.setblocking(False)
    bus = RecordingBus()
    frontend = sim_service.SocketFrontend(SimpleNamespace(bus=bus), listener, {})
    request = bytes((0x11, 1, 1, 0x2A, 1, 2, 3, 4))  # XFER to 0x11: a command frame, 1 byte read back
    body = bytes((sim_service.XFER,)) + request
    frame = sim_service._LENGTH.pack(len(body)) + body
    try:
        gone = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        gone.connect(str(path))
        gone.sendall(frame)
        gone.close()  # the client's timeout: it hangs up before the service got to it
        staying = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        staying.connect(str(path))
        staying.sendall(frame)
        staying.settimeout(5)
        frontend.poll()
        assert staying.recv(5)[4] == sim_service.OK, "a client that waits is answered"
        assert bus.transfers == [(0x11, bytes((0x2A, 1, 2, 3, 4)), 1)], "once: the hung-up client's was dropped"
        staying.close()
    finally:
        frontend.close()
        listener.close()


def test_sigterm_stops_a_shell_script_midway_and_says_where(state_dir: Path, tmp_path: Path) -> None:  # noqa: F811
    config = str(quick_config(tmp_path))
    assert bioscara("home", "j1", "--config", config).returncode == 0
    start = position(Path(config))
    target = -2.5 if start > 0 else 2.5
    script = tmp_path / "move.txt"
    # A second of the move, then a long wait: the signal comes once the script says it waits.
    script.write_text(f"configure\nactivate\nmode j1 position\nset j1 position {target}\nwait 1\nwait 30\n")
    with running("shell", "--script", str(script), "--config", config) as shell:
        started, seen = wait_for_line(shell.stdout, re.compile(r"^> wait 30$"), 60.0)
        assert started is not None, seen
        shell.send_signal(signal.SIGTERM)
        _, err = shell.communicate(timeout=30)
    assert shell.returncode == 128 + signal.SIGTERM, err
    stopped = re.search(r"^leaving the shell: stopped j1 at ([-+][0-9.]+) rad, j2 \(not homed\), j3 \(not homed\), "
                        r"j4 \(not homed\); the joints keep holding$", err, re.M)
    assert stopped is not None and "Traceback" not in err, err
    where = float(stopped.group(1))
    assert abs(where - start) > 0.3 and abs(where - target) > 0.1, "stopped midway"
    stays(Path(config), where)
