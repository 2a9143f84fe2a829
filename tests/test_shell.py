"""`bioscara shell`: the console interpreter on the simulated bus, in virtual time where it can be.

What a command sends is observed on the wire (the conftest Recorder wraps the bus transfer) and in
the simulated joint's own firmware flags.
"""

from __future__ import annotations

import io
import re
import struct
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from bioscara.arm import Arm, Lifecycle
from bioscara.bus.sim import SimBus
from bioscara.cli import main
from bioscara.commands.shell import Context, _completer, interactive
from bioscara.config import ArmConfig
from bioscara.firmware.spec import protocol as P
from bioscara.hardware import sim_joint_specs
from bioscara.shell_interpreter import Shell

from conftest import Recorder

J1 = 0x11


class Console:
    """A shell with its output and error lines collected."""

    def __init__(self, config: ArmConfig, bus: SimBus, arm: Arm, **options: object) -> None:
        self.out: list[str] = []
        self.err: list[str] = []
        self.shell = Shell(Context(config, bus, arm), self.out.append, self.err.append, priority=None,
                           **options)  # type: ignore[arg-type]

    def ok(self, *lines: str) -> None:
        for line in lines:
            assert self.shell.execute(line), (line, self.err)

    def fails(self, line: str) -> str:
        """Run a line that must fail; its one error line."""
        before = len(self.err)
        assert not self.shell.execute(line), line
        assert len(self.err) == before + 1, self.err[before:]
        return self.err[-1]


@pytest.fixture
def console(config: ArmConfig, bus: SimBus, arm: Arm) -> Console:
    return Console(config, bus, arm)


@pytest.fixture
def expert(config: ArmConfig, bus: SimBus, arm: Arm) -> Console:
    return Console(config, bus, arm, expert=True)


def test_a_script_reads_and_writes_exactly_these_frames(expert: Console, recorder: Recorder, bus: SimBus) -> None:
    script = ["# raw access to j1, before the arm is configured",
              "read j1 PING",
              "read j1 ANGLEMOVED",
              "write j1 SETUP 30 20 0 0",
              "write j1 SETRPM 12.5",
              "write j1 SETCURRENT 0"]
    assert expert.shell.run_lines(script, "test")
    assert recorder.frames == [
        (J1, bytes([P.PING]), 2),  # opening the joint: one PING
        (J1, bytes([P.PING]), 2),
        (J1, bytes([P.ANGLEMOVED]), 5),
        (J1, bytes([P.SETUP, 30, 20, 0, 0]), 1),
        (J1, bytes([P.SETRPM]) + struct.pack("<f", 12.5), 1),
        (J1, bytes([P.SETCURRENT, 0]), 1),
    ]
    assert bus.joint(J1).core.flags & P.FLAG_NOTENABLED, "SETCURRENT 0 disabled the joint"
    assert "j1 PING: ack = 'O'  [NOTHOMED|NOTENABLED]" in expert.out
    assert any(line.startswith("j1 ANGLEMOVED: angle = ") and "[deg (motor)]" in line for line in expert.out)
    assert "j1 SETUP 30 20 0 0: accepted  [NOTHOMED]" in expert.out
    assert "j1 SETCURRENT 0: accepted  [NOTHOMED|NOTENABLED]" in expert.out


@pytest.mark.parametrize("arm", ["legacy"], indirect=True)  # the exact legacy frames
def test_read_all_and_lifecycle_use_the_arms_joints(console: Console, recorder: Recorder, arm: Arm) -> None:
    console.ok("configure", "read all IDENTITY")
    assert arm.lifecycle is Lifecycle.INACTIVE
    for address in (0x11, 0x12, 0x13, 0x14):
        # configure's PING, then IDENTITY through the arm's own (open) joint: no second PING
        assert recorder.to(address) == [bytes([P.PING]), bytes([P.IDENTITY])]
    assert sum("(same spec as this host)" in line for line in console.out) == 4
    console.ok("activate")
    assert arm.lifecycle is Lifecycle.ACTIVE
    recorder.clear()
    console.ok("deactivate", "cleanup")
    assert arm.lifecycle is Lifecycle.UNCONFIGURED
    # ... and the watchdog activate turned on goes off again: a host of another kind may come next.
    assert recorder.to(J1) == [bytes([P.STOP, 0]), bytes([P.SETHOLDCURRENT, 0]), bytes([P.SETCURRENT, 0]),
                               bytes([P.SETBRAKEMODE, 0]), bytes([P.WATCHDOG]) + P.register("WATCHDOG").encode(0)]
    assert "cannot activate while unconfigured" in console.fails("activate")


def test_raw_write_is_refused_without_expert_and_nothing_is_sent(console: Console, recorder: Recorder) -> None:
    error = console.fails("write j1 SETCURRENT 0")
    assert "refused" in error and "bioscara shell --expert" in error
    assert recorder.frames == []


@pytest.mark.parametrize("line, message", [
    ("write j9 SETCURRENT 0", "no joint 'j9'; the arm has j1, j2, j3, j4 (or all)"),
    ("read J5 PING", "no joint 'j5'"),
    ("write j1 SETCURENT 0", "no register 'SETCURENT' (did you mean SETCURRENT?)"),
    ("read j1 NOSUCH", "no register 'NOSUCH'"),
    ("write j1 SETCURRENT 101", "SETCURRENT.drive_current = 101 is outside the valid range (0..100)"),
    ("write j1 SETCURRENT 300", "SETCURRENT.drive_current = 300 is outside the valid range (0..100)"),
    ("write j1 SETCURRENT 1.5", "SETCURRENT.drive_current must be an integer, got '1.5'"),
    ("write j1 SETRPM fast", "SETRPM.rpm must be a number, got 'fast'"),
    ("write j1 SETRPM nan", "SETRPM.rpm = nan is outside the valid range (finite, |value| in [0, 5000])"),
    ("write j1 SETRPM 6000", "SETRPM.rpm = 6000.0 is outside the valid range"),
    ("write j1 MOVESTEPS 3000000000", "MOVESTEPS.steps = 3000000000 does not fit a signed 32-bit integer"),
    ("write j1 SETUP 20", "SETUP takes 4 values (drive_current hold_current reserved reserved), got 1"),
    ("write j1 STOP 1", "STOP.reserved = 1 is outside the valid range (0..0)"),
    ("write j1 ANGLEMOVED 0", "ANGLEMOVED cannot be written"),
    ("read j1 SETCURRENT", "SETCURRENT cannot be read"),
    ("read j1 ENABLEPID", "ENABLEPID is declared by the original protocol but not implemented"),
    ("write j1", "usage: write JOINT|all REGISTER VALUE..."),
    ("reed j1 PING", "unknown command 'reed' (did you mean read?)"),
    ("read j1 'PING", "No closing quotation"),
])
def test_bad_commands_say_why_and_send_nothing(expert: Console, recorder: Recorder, line: str,
                                               message: str) -> None:
    error = expert.fails(line)
    assert error.startswith("error: ") and message in error
    assert recorder.frames == []


def test_a_rejected_frame_reports_the_joints_reason(expert: Console, bus: SimBus) -> None:
    expert.ok("write j1 SETUP 20 20 0 0", "write j1 HOME 0 10 30 20")
    error = expert.fails("write j1 HOME 0 10 30 20")  # a second blocking command while the first runs
    assert "the joint rejected HOME: a blocking command is already running" in error
    expert.ok("read j1 LASTERROR")
    assert "reason = 5 (a blocking command is already running), register = 45 (HOME), count = 1" in expert.out[-1]


def test_run_stops_at_the_failing_line_and_names_it(console: Console, arm: Arm, tmp_path: Path) -> None:
    script = tmp_path / "bring-up.txt"
    script.write_text("# bring the arm up\n\nread j1 PING  # liveness\nread j1 NOSUCH\nconfigure\n")
    error = console.fails(f"run {script}")
    assert error == f"{script}:4: error: no register 'NOSUCH'; `regs` lists them"
    assert arm.lifecycle is Lifecycle.UNCONFIGURED, "nothing after the failing line ran"
    assert console.out[:2] == ["> read j1 PING  # liveness", "j1 PING: ack = 'O'  [NOTHOMED|NOTENABLED]"]

    assert not console.shell.execute(f"run --keep-going {script}")
    assert arm.lifecycle is Lifecycle.INACTIVE, "--keep-going ran the rest"

    script.write_text(f"run {script}\n")
    assert "is already running" in console.fails(f"run {script}")
    assert "No such file" in console.fails(f"run {tmp_path / 'missing.txt'}")


def test_quit_ends_a_script(console: Console, arm: Arm) -> None:
    assert console.shell.run_lines(["quit", "configure"], "test")
    assert console.shell.done and arm.lifecycle is Lifecycle.UNCONFIGURED


def test_start_stop_restart_the_communicator(console: Console) -> None:
    shell = console.shell
    console.ok("start 50")
    assert shell.communicator.running and shell.communicator.frequency == 50
    assert shell.prompt() == "bioscara[unconfigured @50Hz]> "
    _wait_for(lambda: shell.communicator.stats.cycles >= 3)
    assert "running at 50 Hz; `stop` it to change the rate" in console.fails("start 100")
    console.ok("start")
    assert console.out[-1] == "communicator already running at 50 Hz"
    cycles = shell.communicator.stats.cycles
    console.ok("restart")
    assert shell.communicator.running
    _wait_for(lambda: shell.communicator.stats.cycles > cycles)
    console.ok("stop")
    assert not shell.communicator.running
    cycles, shown = shell.communicator.stats.cycles, len(console.out)
    console.ok("stats")
    assert shell.communicator.stats.cycles == cycles, "stopped: no more cycles"
    stats = console.out[shown:]
    assert stats[0] == "communicator stopped, target 50 Hz, scheduling: normal"
    assert stats[1].startswith(f"  {cycles} cycles, rate ") and "jitter" in stats[1] and "overruns" in stats[1]
    assert stats[2].startswith("  cycle duration mean ")
    assert stats[3] == "link health, bus sim:virtual"
    assert stats[4].split() == ["joint", "addr", "transactions", "failed", "attempts", "lost", "last", "error"]
    assert [row.split()[:2] for row in stats[5:]] == [["j1", "0x11"], ["j2", "0x12"], ["j3", "0x13"], ["j4", "0x14"]]
    console.ok("stop")
    assert console.out[-1] == "communicator already stopped"
    console.ok("start 200")
    assert shell.communicator.frequency == 200 and shell.communicator.stats.cycles < cycles + 50
    console.ok("stop")
    assert "cycle rate must be in (0, 10000] Hz" in console.fails("start 0")


def test_home_and_move_a_joint_through_modes_in_virtual_time(console: Console, bus: SimBus, arm: Arm) -> None:
    console.ok("configure", "activate")
    assert "cannot start position mode before homing" in console.fails("mode j4 position")
    console.ok("mode j4 home", "set j4 home 1", "wait 5", "mode j4")
    assert arm["j4"].state.home == 1.0 and arm["j4"].command.home == 0.0
    assert console.out[-1] == "j4: home"
    console.ok("mode j4 position", "set j4 position 1.0", "wait 3", "state")
    assert abs(bus.joint_position(0x14) - 1.0) < 0.01
    j4 = next(line for line in console.out if line.startswith("j4 ") and "position" in line).split()
    assert j4[1:3] == ["-", "position"] and abs(float(j4[3]) - 1.0) < 0.002 and j4[4] == "rad"
    console.ok("set j3 velocity 0.5")
    assert console.out[-1] == "j3: velocity command 0.5 (not in velocity mode: j3)"
    assert "position 5 is outside [-3.01069, 3.01069]" in console.fails("set j4 position 5")
    assert "|velocity| 20 exceeds max_velocity 10" in console.fails("set j4 velocity -20")
    assert "home takes +1, -1" in console.fails("set j4 home 2")
    assert "no command mode 'speed'" in console.fails("set j4 speed 1")
    console.ok("mode all off")
    assert all(not aj.modes for aj in arm.joints.values())


def test_a_fault_in_the_cycle_fails_the_command_that_saw_it(console: Console, bus: SimBus, arm: Arm) -> None:
    console.ok("configure", "activate", "wait 0.05")
    bus.joint(0x12).power_cycle()  # j2 reboots: it stops answering for its boot time
    error = console.fails("wait 0.05")
    assert "arm fault, joints disabled (arm inactive)" in error and "0x12" in error
    console.ok("state")  # reported once
    assert any(line.startswith("fault: ") for line in console.out)


def test_completion_candidates(console: Console, tmp_path: Path) -> None:
    complete = console.shell.complete
    assert complete("re") == ["restart", "read", "regs"]
    assert complete("ex") == ["exit"]
    assert complete("read ") == ["j1", "j2", "j3", "j4", "all"]
    assert complete("read j1 ang") == ["ANGLEMOVED"]
    assert complete("read j1 SET") == [], "nothing readable starts with SET"
    assert complete("write all setc") == ["SETCURRENT"]
    assert complete("write j1 SETCURRENT ") == []
    assert complete("mode j2 ") == ["position", "velocity", "home", "off"]
    assert complete("set j2 v") == ["velocity"]
    assert complete("help wr") == ["write"]
    assert complete("stats ") == []
    (tmp_path / "lift.txt").write_text("")
    (tmp_path / "lib").mkdir()
    assert complete(f"run {tmp_path}/li") == [f"{tmp_path}/lib/", f"{tmp_path}/lift.txt"]
    assert complete(f"run --keep-going {tmp_path}/lif") == [f"{tmp_path}/lift.txt"]


def test_help_and_regs(console: Console) -> None:
    console.ok("help")
    assert any(line.startswith("write JOINT|all REGISTER VALUE...") for line in console.out)
    console.ok("help write")
    assert console.out[-4].startswith("write JOINT|all REGISTER VALUE...: write a raw register frame")
    console.ok("regs")
    assert "0x19  SETCURRENT           W    write: drive_current u8 0..100 [%]" in console.out
    assert any(line.startswith("0x2e  HOMEOFFSET") and " RW " in line for line in console.out)
    console.ok("regs home")
    assert console.out[-2:] == ["  blocking: runs in the firmware main loop holding BUSY",
                                "  sets BUSY|NOTHOMED when accepted"]


def test_interactive_line_editing_history_and_ctrl_c(console: Console, arm: Arm, tmp_path: Path) -> None:
    from prompt_toolkit.input import create_pipe_input
    from prompt_toolkit.output import DummyOutput

    history = tmp_path / "state" / "shell_history"
    with create_pipe_input() as keys:
        # An edited line (backspace), a half-typed configure dropped by Ctrl-C, then Ctrl-D leaves.
        keys.send_text("read j1 PINX\x7fG\r" "configure\x03" "\x04")
        assert interactive(console.shell, history, input=keys, output=DummyOutput()) == 0
    assert console.out == ["j1 PING: ack = 'O'  [NOTHOMED|NOTENABLED]"] and console.err == []
    assert arm.lifecycle is Lifecycle.UNCONFIGURED
    assert "+read j1 PING" in history.read_text().splitlines()
    assert "configure" not in history.read_text()
    assert history.stat().st_mode & 0o777 == 0o600 and history.parent.stat().st_mode & 0o777 == 0o700, "private"


def test_the_line_editors_completer_replaces_the_word_being_typed(console: Console) -> None:
    from prompt_toolkit.completion import CompleteEvent
    from prompt_toolkit.document import Document

    completions = list(_completer(console.shell).get_completions(Document("read j1 angle"), CompleteEvent()))
    assert [(c.text, c.start_position) for c in completions] == [("ANGLEMOVED", -5)]
    completions = list(_completer(console.shell).get_completions(Document("mode "), CompleteEvent()))
    assert [(c.text, c.start_position) for c in completions] == [(j, 0) for j in ("j1", "j2", "j3", "j4", "all")]


def test_cli_script_and_piped_stdin_exit_codes(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    good = tmp_path / "good.txt"
    good.write_text("read j1 PING\nconfigure\nstate\n")
    assert main(["shell", "--script", str(good)]) == 0
    assert "arm inactive" in capsys.readouterr().out
    bad = tmp_path / "bad.txt"
    bad.write_text("read j1 PING\nwrite j1 SETCURRENT 0\nconfigure\n")
    assert main(["shell", "--script", str(bad)]) == 1
    captured = capsys.readouterr()
    assert f"{bad}:2: error: raw register writes" in captured.err and "arm inactive" not in captured.out
    monkeypatch.setattr(sys, "stdin", io.StringIO("write j1 SETCURRENT 0\nread j1 PING\n"))
    assert main(["shell", "--expert"]) == 0
    assert "j1 SETCURRENT 0: accepted" in capsys.readouterr().out


def _wait_for(condition: object, timeout: float = 5.0, clock: Callable[[], float] = time.monotonic) -> None:
    """Until `condition()` holds; at most `timeout` s on `clock` (a bus clock: simulated seconds)."""
    deadline = clock() + timeout
    while not condition():  # type: ignore[operator]
        assert clock() < deadline, "timed out"
        time.sleep(0.001)


def test_the_shell_keeps_active_joints_alive_and_names_fault_causes(config: ArmConfig, bus: SimBus,
                                                                    arm: Arm) -> None:
    """The communicator runs whenever the arm is active; `stop` warns; a fault names its cause.

    On the virtual clock, with the shipped deadman and watchdog: simulated time passes only as the
    communicator (or the test) lets it, so a loaded machine cannot starve the joints of traffic.
    """
    console = Console(config, bus, arm, keep_alive=True)
    shell = console.shell
    try:
        console.ok("configure", "activate")
        assert shell.communicator.running, "started by configure"
        assert any("keeps the joints fed" in line for line in console.out)
        console.ok("mode j4 home", "set j4 home 1")
        _wait_for(lambda: arm["j4"].state.home == 1.0, timeout=20.0, clock=bus.monotonic)
        console.ok("mode j4 position", "set j4 position 2.5", "wait 0.2")
        assert arm.fault is None and arm["j4"].joint.is_enabled()
        assert shell.communicator.stats.cycles > 0
        console.ok("stop")
        assert console.err[-1].startswith("warning: the arm is active") and "deadman" in console.err[-1]
        console.ok("set j4 position -2.9", "wait 0.05")  # a 0.7 s move starts, then nobody talks to j4
        bus.sleep(2.0)
        error = console.fails("wait 0.1")
        assert "j4: deadman: the joint stopped and disabled itself" in error, error
        console.ok("state")  # where a user looks next: the fault and the joint's own cause, with the silence
        assert any(line.startswith("fault: ") for line in console.out)
        assert any(re.fullmatch(r"j4: the joint disabled itself: its deadman, after \d+ ms without traffic from "
                                r"this host \(its timeout is 100 ms\)", line) for line in console.out), console.out
    finally:
        shell.close()


def test_stats_count_from_start_and_restart_resets_them(console: Console) -> None:
    shell = console.shell
    console.ok("wait 0.5")  # cycles run by hand, then a pause (the user typing)
    shell.context.bus.sleep(5.0)
    console.ok("start 100")
    _wait_for(lambda: shell.communicator.stats.cycles >= 5)
    console.ok("stop")
    assert shell.communicator.stats.cycles < 40 and shell.communicator.stats.period_max < 1.0, \
        "neither the earlier cycles nor the pause are counted"
    console.ok("start")
    _wait_for(lambda: shell.communicator.stats.cycles >= 300)
    console.ok("restart", "stop")
    assert shell.communicator.stats.cycles < 300, "restart counts afresh"



def test_errors_are_coloured_on_a_terminal_not_escaped(tmp_path: Path) -> None:
    """`bioscara shell` in a pseudo-terminal, as a user runs it: an error comes in red, with the
    terminal's escape codes intact (prompt_toolkit's stdout patch used to print them as `?[31m`)."""
    import os
    import pty
    import select

    pid, fd = pty.fork()
    if pid == 0:  # the child: the shell on the in-process simulator, its own state directory
        os.environ.update(BIOSCARA_BUS="sim:virtual", XDG_STATE_HOME=str(tmp_path))
        os.execv(sys.executable, [sys.executable, "-m", "bioscara.cli", "shell"])
    seen = b""

    def read_until(marker: bytes, timeout: float = 60.0, start: int = 0) -> bool:
        """Read the terminal until `marker` shows up after `start`, answering cursor position
        requests as a terminal does."""
        nonlocal seen
        deadline = time.monotonic() + timeout
        while seen.find(marker, start) < 0 and time.monotonic() < deadline:
            if select.select([fd], [], [], 0.1)[0]:
                try:
                    data = os.read(fd, 65536)
                except OSError:  # the shell has gone
                    break
                seen += data
                for _ in range(data.count(b"\x1b[6n")):
                    os.write(fd, b"\x1b[1;1R")
        return seen.find(marker, start) >= 0
    try:
        assert read_until(b"bioscara[unconfigured]>"), seen[-300:]
        os.write(fd, b"frobnicate\r")
        assert read_until(b"`help` lists them"), seen[-300:]
        assert b"\x1b[31merror: unknown command 'frobnicate'" in seen
        assert b"?[31m" not in seen and b"^[[31m" not in seen
        assert read_until(b"bioscara[unconfigured]>", 30.0, start=seen.index(b"`help` lists them"))
        os.write(fd, b"quit\r")  # typed at the next prompt
        read_until(b"never printed", timeout=30.0)  # drained until the shell closes its terminal
        assert os.waitpid(pid, 0)[1] == 0
        pid = 0
    finally:
        if pid:
            os.kill(pid, 9)
            os.waitpid(pid, 0)
        os.close(fd)


def test_protocol_chooses_the_shells_and_the_panels_protocol(config: ArmConfig) -> None:
    """`--protocol` is honoured where it is offered (the shell and the panel used to ignore it)."""
    import argparse

    from bioscara.commands.panel import open_model
    from bioscara.commands.shell import open_context
    from bioscara.session import Session
    context = open_context(config, "legacy")
    try:
        assert context.arm.protocol == "legacy"
    finally:
        context.bus.close()
    session = Session(argparse.Namespace(protocol="legacy", config=None, bus="sim:virtual"))
    model = open_model(session, 100.0, threaded=False)
    try:
        assert model.arm.protocol == "legacy"
    finally:
        model.close()
        session.close()


def test_a_pause_after_configure_keeps_the_joints_on_protocol_v2(config: ArmConfig,
                                                                 caplog: pytest.LogCaptureFixture) -> None:
    """Two seconds between `configure` and `activate` (a person typing) used to print four
    "serves the legacy map again" warnings: the communicator now keeps the joints fed from `configure`."""
    bus = SimBus(sim_joint_specs(config), realtime=True)
    arm = Arm(config, bus)
    console = Console(config, bus, arm, keep_alive=True)
    try:
        console.ok("configure")
        assert console.shell.communicator.running
        cycles = console.shell.communicator.stats.cycles
        time.sleep(2.0)  # the pause is the scenario: the host has nothing to say for 2 s
        assert console.shell.communicator.stats.cycles > cycles
        console.ok("activate")
        assert "legacy map" not in caplog.text
        assert all(aj.joint.protocol == "v2" for aj in arm.joints.values())
    finally:
        console.shell.close()
        bus.close()


def test_leaving_the_shell_stops_the_arm_says_so_and_the_joints_keep_holding(config: ArmConfig) -> None:
    """Ctrl-D used to disable (freewheel) every joint without a word."""
    import argparse

    from bioscara.commands.shell import close_context
    from bioscara.session import Session

    bus = SimBus(sim_joint_specs(config))
    arm = Arm(config, bus)
    console = Console(config, bus, arm)
    console.ok("configure", "activate")
    said: list[str] = []
    session = Session(argparse.Namespace(bus="sim:virtual"))
    session.err = said.append  # type: ignore[method-assign]
    close_context(console.shell, Context(config, bus, arm), session)
    assert len(said) == 1 and said[0].startswith("leaving the shell: stopped j1 ") and "keep holding" in said[0]
    assert arm.lifecycle is Lifecycle.UNCONFIGURED
    assert all(not bus.joint(aj.config.address).core.flags & P.FLAG_NOTENABLED for aj in arm.joints.values()), \
        "still enabled: holding, not freewheeling"
