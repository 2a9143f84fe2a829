"""One arm, many programs (issue 25): programs that only read run beside the one that commands,
on the shared simulated arm, each a real process in real time, as a user runs them. Every wait is
a bounded wait on a condition; every assertion is on what the user sees (exit status, messages,
positions)."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
from collections.abc import Callable
from pathlib import Path

import pytest

from bioscara import sim_service
from sim_session import bioscara, quick_config, state_dir, wait_until  # noqa: F401 (fixtures)

Spawn = Callable[..., subprocess.Popen[str]]


def _run(spawn: Spawn, *argv: str, timeout: float = 60.0) -> tuple[int, str, str]:
    process = spawn(*argv)
    out, err = process.communicate(timeout=timeout)
    return process.returncode, out, err


def _at(out: str, joint: str) -> float:
    """Where `bioscara move` says the joint ended (joint units)."""
    found = re.search(rf"^{joint} at ([+-]\d+\.\d+) ", out, flags=re.M)
    assert found, out
    return float(found.group(1))


def _commander(state_dir: Path) -> dict | None:
    """Who commands the shared arm, as its record in the state directory says."""
    try:
        return json.loads((state_dir / "arm-sim.json").read_text())
    except (OSError, ValueError):
        return None


@pytest.fixture
def config(tmp_path: Path, state_dir: Path) -> str:
    """The quick arm; a 1 s watchdog: the shared machine can stall the simulated arm's process
    beyond the shipped 100 ms (the host's silence a deadman would then see is not this test's)."""
    return str(quick_config(tmp_path, watchdog_ms=1000))


class Lines:
    """What a background program prints, line by line, as it prints it."""

    def __init__(self, process: subprocess.Popen[str]) -> None:
        self.process = process
        self.lines: list[str] = []
        assert process.stdout is not None
        self._reader = threading.Thread(target=lambda: self.lines.extend(process.stdout), daemon=True)  # type: ignore[arg-type]
        self._reader.start()

    def finish(self, timeout: float = 20.0) -> tuple[list[str], str]:
        self.process.send_signal(signal.SIGINT)
        self.process.wait(timeout=timeout)
        self._reader.join(timeout=timeout)
        assert self.process.stderr is not None
        return self.lines, self.process.stderr.read()


def test_a_monitor_beside_home_all_and_a_move_sees_both_and_disturbs_neither(config: str, bioscara: Spawn) -> None:
    monitor = Lines(bioscara("monitor", "--config", config, "--rate", "20", "--json"))
    assert wait_until(lambda: len(monitor.lines) >= 2, timeout=30), "the monitor samples"
    code, out, err = _run(bioscara, "home", "all", "--config", config, timeout=120)
    assert code == 0, err
    code, out, err = _run(bioscara, "move", "j3", "1.0", "--config", config)
    assert code == 0 and _at(out, "j3") == pytest.approx(1.0, abs=2e-3), err
    count = len(monitor.lines)
    assert wait_until(lambda: len(monitor.lines) >= count + 2), "the monitor samples on"
    lines, err = monitor.finish()
    samples = [json.loads(line) for line in lines]
    assert monitor.process.returncode == 0 and samples[-1]["summary"]["errors"] == 0, err
    j3 = [next(j for j in s["joints"] if j["joint"] == "j3") for s in samples[:-1]]
    assert j3[0]["position"] is None and "NOTHOMED" in j3[0]["flags"]
    assert any(j["position"] is not None and j["position"] > 2.5 for j in j3), "it saw j3 homed at its stop"
    assert j3[-1]["position"] == pytest.approx(1.0, abs=0.01) and j3[-1]["flags"] == [], "and where the move left it"


def test_info_beside_a_move_shows_what_the_commander_reads(config: str, state_dir: Path, bioscara: Spawn) -> None:
    assert _run(bioscara, "home", "j1", "--config", config, timeout=120)[0] == 0
    move = bioscara("move", "j1", "2.5", "--config", config)  # 5.5 rad at 1 rad/s
    assert wait_until(lambda: _commander(state_dir) is not None)
    code, out, err = _run(bioscara, "info", "j1", "--config", config, "--json")
    assert code == 0, err
    info = json.loads(out)
    assert info["commanded_by"] == {"pid": move.pid, "program": f"bioscara move j1 2.5 --config {config}"}
    assert -3.1 < info["position"] < 2.51 and info["enabled"] and info["spec_matches"]
    out, err = move.communicate(timeout=60)
    assert move.returncode == 0 and _at(out, "j1") == pytest.approx(2.5, abs=2e-3), err


def test_a_second_commander_is_refused_by_name_then_takes_over_when_asked(config: str, state_dir: Path,
                                                                          bioscara: Spawn) -> None:
    assert _run(bioscara, "home", "j1", "--config", config, timeout=120)[0] == 0
    first = bioscara("move", "j1", "2.5", "--config", config)
    assert wait_until(lambda: _commander(state_dir) is not None)
    code, out, err = _run(bioscara, "move", "j1", "0.0", "--config", config)
    assert code == 1 and not out
    assert f"the arm on sim: is commanded by pid {first.pid} (bioscara move j1 2.5 --config {config})" in err
    assert "--take-over" in err and "Traceback" not in err
    assert first.poll() is None, "the refused program disturbed nothing"
    code, out, err = _run(bioscara, "move", "j1", "0.0", "--config", config, "--take-over")
    assert code == 0 and _at(out, "j1") == pytest.approx(0.0, abs=2e-3), err
    assert first.wait(timeout=10) != 0, "the first program was stopped"
    code, out, err = _run(bioscara, "info", "j1", "--config", config, "--json")
    info = json.loads(out)
    assert code == 0 and info["commanded_by"] is None and info["position"] == pytest.approx(0.0, abs=0.01)


SCRIPT = """
import json, time
from bioscara import motion
from bioscara.communicator import Communicator
from bioscara.hardware import open_arm

with open_arm() as arm:
    arm.activate()
    comm = Communicator(arm, frequency=100.0)
    motion.home(arm, comm, ["j1", "j3"])
    motion.move_to(arm, comm, {"j1": 0.5, "j3": -1.0})
    time.sleep(5.0)  # the script does something else; nobody talks to the joints
    arm.cycle()
    print(json.dumps({name: [aj.joint.is_enabled(), aj.state.position] for name, aj in arm.joints.items()
                      if name in ("j1", "j3")}), flush=True)
"""


def test_a_script_that_homes_moves_and_sleeps_finds_its_joints_still_enabled(
        config: str, private_home: Path, tmp_path: Path) -> None:
    user_config = private_home / "config" / "bioscara" / "arm.toml"
    user_config.parent.mkdir(parents=True)
    user_config.write_text(Path(config).read_text())  # the script's open_arm() reads it, as the CLI does
    script = tmp_path / "script.py"
    script.write_text(SCRIPT)
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout.splitlines()[-1])
    assert result["j1"][0] and result["j3"][0], f"a holding joint was disabled while the script slept: {result}"
    assert result["j1"][1] == pytest.approx(0.5, abs=0.01) and result["j3"][1] == pytest.approx(-1.0, abs=0.01)


def test_kill_9_of_a_commander_then_of_the_service(config: str, state_dir: Path, bioscara: Spawn) -> None:
    assert _run(bioscara, "home", "j1", "--config", config, timeout=120)[0] == 0
    move = bioscara("move", "j1", "2.5", "--config", config)
    assert wait_until(lambda: _commander(state_dir) is not None)
    move.kill()
    move.wait(timeout=10)
    code, out, err = _run(bioscara, "move", "j1", "0.0", "--config", config)
    assert code == 0 and _at(out, "j1") == pytest.approx(0.0, abs=2e-3), f"a killed commander holds nothing: {err}"
    status = sim_service.status(state_dir)
    assert status is not None
    os.kill(status["pid"], signal.SIGKILL)
    assert wait_until(lambda: sim_service.status(state_dir) is None)
    code, out, err = _run(bioscara, "info", "j1", "--config", config, "--json")
    assert code == 0, err
    info = json.loads(out)
    assert info["position"] is None and not info["homed"], "a new simulated arm, booted afresh"


HOLDER = """
import sys
from bioscara.bus.smbus import SMBusBus
bus = SMBusBus(1, smbus_factory=lambda number: object())  # /dev/i2c-1 as every process on a Pi opens it
bus.commander.claim()
print("held", flush=True)
sys.stdin.read()  # commands until its input closes
"""


def test_on_a_raspberry_pi_bus_every_process_meets_the_same_commander_lock() -> None:
    from bioscara.bus.smbus import SMBusBus
    from bioscara.commander import ArmBusyError

    bus = SMBusBus(1, smbus_factory=lambda number: object())
    assert bus.arm_lock_path() == Path(os.environ["XDG_STATE_HOME"]) / "bioscara" / "arm-smbus-1.lock"
    holder = subprocess.Popen([sys.executable, "-c", HOLDER], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline() == "held\n"
        commander = bus.commander
        assert commander is not None
        with pytest.raises(ArmBusyError, match=f"the arm on smbus:1 is commanded by pid {holder.pid} "):
            commander.claim()
        with commander.watch() as seen:
            assert seen is not None and seen.pid == holder.pid, "a reader learns who commands, and reads from it"
        assert holder.stdin is not None
        holder.stdin.close()
        assert holder.wait(timeout=10) == 0
        commander.claim()  # the lock is free once that program has ended
        commander.release()
    finally:
        if holder.poll() is None:
            holder.kill()
            holder.wait()


def test_a_commander_that_ends_while_a_watcher_asks_it_is_no_read_error(tmp_path: Path) -> None:
    """The race behind a monitor's error count: the watcher finds the lock held and the record
    naming the commander, then the command ends before the watcher's question reaches it. The
    watcher watches again and reads the joint itself, as it does with nobody commanding."""
    from bioscara.bus.sim import SimBus
    from bioscara.commander import Commander
    from bioscara.config import read_config
    from bioscara.hardware import sim_joint_specs
    from bioscara.link.base import LinkState
    from bioscara.link.watched import WatchedLink

    lock = tmp_path / "arm-test.lock"
    commanding, watching = Commander(lock, "test"), Commander(lock, "test")  # two programs' views
    commanding.claim()
    commanding.publish(lambda: {"j1": {"address": 0x11, "read": True, "flags": 0, "position_deg": 1.0,
                                       "velocity_rpm": 0.0, "offset": 0.0}})
    asked = watching.published

    def ends_as_it_is_asked(holder):  # type: ignore[no-untyped-def]
        commanding.release()
        return asked(holder)
    watching.published = ends_as_it_is_asked  # type: ignore[method-assign]
    bus = SimBus(sim_joint_specs(read_config()))
    try:
        link = WatchedLink(bus, 0x11, "j1", watching)
        state = link.cycle(None)
        assert isinstance(state, LinkState) and link.holder is None, "read from the joint once the commander left"
        assert state.position_deg != 1.0
    finally:
        bus.close()


def _moving_commander(spawn: Spawn, config: str, state_dir: Path,
                      tmp_path: Path) -> tuple[subprocess.Popen[str], str]:
    """A shell script that sends j1 from its end stop to +2.5 rad and then holds it for a minute,
    and its command line, once it commands the arm."""
    assert _run(spawn, "home", "j1", "--config", config, timeout=120)[0] == 0
    script = tmp_path / "hold.txt"
    script.write_text("configure\nactivate\nmode j1 position\nset j1 position 2.5\nwait 60\n")
    first = spawn("shell", "--script", str(script), "--config", config)
    assert wait_until(lambda: _commander(state_dir) is not None, timeout=30)
    return first, f"bioscara shell --script {script} --config {config}"


def _stopped_by_the_take_over(first: subprocess.Popen[str]) -> float:
    """The first commander ended on the SIGTERM of the take-over, its joint stopped: where."""
    out, err = first.communicate(timeout=30)
    assert first.returncode == 128 + signal.SIGTERM and "interrupted (SIGTERM)" in err, err
    stopped = re.search(r"^leaving the shell: stopped j1 at ([-+]\d+\.\d+) rad", err, flags=re.M)
    assert stopped is not None, err
    return float(stopped.group(1))


def test_a_second_shell_is_refused_by_name_then_takes_over_when_asked(config: str, state_dir: Path,
                                                                     tmp_path: Path, bioscara: Spawn) -> None:
    first, program = _moving_commander(bioscara, config, state_dir, tmp_path)
    script = tmp_path / "to-zero.txt"
    script.write_text("configure\nactivate\nmode j1 position\nset j1 position 0.0\nwait 1\n")
    code, out, err = _run(bioscara, "shell", "--script", str(script), "--config", config)
    assert code == 1 and "Traceback" not in err
    assert f"the arm on sim: is commanded by pid {first.pid} ({program})" in err
    assert "--take-over" in err and first.poll() is None, "the refused shell disturbed nothing"
    code, out, err = _run(bioscara, "shell", "--script", str(script), "--config", config, "--take-over")
    assert code == 0 and "Traceback" not in err, err
    taken_at = _stopped_by_the_take_over(first)
    left = re.search(r"^leaving the shell: stopped j1 at ([-+]\d+\.\d+) rad", err, flags=re.M)
    assert left is not None, err
    assert abs(float(left.group(1))) < max(abs(taken_at) - 0.2, 2e-3), "the shell moved j1 toward 0 rad"
    assert _commander(state_dir) is None, "and let go of the arm as it ended"


def _without_breaks(text: str) -> str:
    return re.sub(r"[\s│]+", "", text)


def test_a_second_panel_is_refused_by_name_then_takes_over_when_asked(config: str, state_dir: Path,
                                                                     tmp_path: Path, bioscara: Spawn) -> None:
    from tests.user_programs import Terminal

    first, program = _moving_commander(bioscara, config, state_dir, tmp_path)
    refused = Terminal("panel", "--config", config, lines=80)  # room in the log for the whole refusal
    try:
        refused.wait_for("Configure")
        since = len(refused.shown)
        refused.press("a", "configure: the arm on sim: is")
        said = f"is commanded by pid {first.pid} ({program}) since"
        # the log wraps the message in its box: compare without the line breaks and the box's sides
        assert wait_until(lambda: _without_breaks(said) in _without_breaks(refused.read()[since:]), timeout=30)
        assert _without_breaks("or take over with --take-over (it is stopped)") in _without_breaks(refused.shown)
        assert "[ERROR" not in refused.shown, "said in words, without the original driver's error code"
        assert first.poll() is None, "the refused panel disturbed nothing"
        os.write(refused.fd, b"q")
        assert refused.wait_for_exit() == 0
    finally:
        refused.close()
    panel = Terminal("panel", "--config", config, "--take-over")
    try:
        panel.wait_for("Configure")
        panel.press("a", "configure: done")
        _stopped_by_the_take_over(first)
        assert (_commander(state_dir) or {}).get("program", "").startswith("bioscara panel --config"), \
            "the panel commands the arm now"
        os.write(panel.fd, b"q")
        assert panel.wait_for_exit() == 0 and "Traceback" not in panel.shown
    finally:
        panel.close()
    assert _commander(state_dir) is None, "and let go of it as it ended"
