"""The shared simulated arm (`sim:`): one background service, state kept between commands, many
clients at once, robust to stale sockets, crashes and concurrent starts.

Each test starts the service explicitly in its own state directory and stops it at the end; waits
are bounded waits on conditions.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import socket
import stat
import subprocess
import threading
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import pytest

from bioscara import cli, sim_service
from bioscara.arm import make_joint
from bioscara.config import read_config
from bioscara.errors import CommError, ConfigError
from bioscara.hardware import sim_joint_specs
from bioscara.sim_server import SimServer
from bioscara.sim_service import ServiceBus
from sim_session import bioscara, quick_config, state_dir, wait_until  # noqa: F401 (fixtures)

SPECS = sim_joint_specs(read_config())
IDLE_EXIT_S = 60.0  # a run that is killed before its teardown leaves no service for longer


def test_state_is_kept_between_commands_and_clients_share_the_arm(
        state_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
        bioscara: Callable[..., subprocess.Popen[str]]) -> None:
    config = str(quick_config(tmp_path))
    assert cli.main(["home", "j3", "--config", config]) == 0
    assert cli.main(["move", "j3", "2.0", "--config", config]) == 0, "the next command finds j3 homed"
    record = tmp_path / "run.csv"
    # Two processes on one joint at once, each in its default protocol: the monitor only watches.
    monitor = bioscara("monitor", "--config", config, "--rate", "20", "--duration", "3", "--record",
                       str(record), "--json")
    assert wait_until(lambda: record.exists() and len(record.read_text().splitlines()) > 3)
    assert cli.main(["move", "j3", "1.0", "--config", config]) == 0, "a move (v2) beside the monitor"
    out, err = monitor.communicate(timeout=30)
    assert monitor.returncode == 0, out[-500:] + err
    assert json.loads(out.splitlines()[-1])["summary"]["errors"] == 0
    with open(record) as f:
        f.readline()
        j3 = [float(row["j3/position"]) for row in csv.DictReader(f)]
    assert j3[0] == pytest.approx(2.0, abs=0.01) and j3[-1] == pytest.approx(1.0, abs=0.01), \
        "the monitor saw the other process's move"
    capsys.readouterr()
    assert cli.main(["plot", str(record), "--json"]) == 0
    assert Path(json.loads(capsys.readouterr().out)["png"]).read_bytes()[:4] == b"\x89PNG"


def test_start_status_stop(state_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["sim", "status"]) == 1
    assert "no simulated arm is running" in capsys.readouterr().out
    assert cli.main(["sim", "--json"]) == 0
    first = json.loads(capsys.readouterr().out)
    assert first["started"] and sorted(first["joints"]) == ["j1", "j2", "j3", "j4"]
    assert first["joints"]["j2"]["address"] == 0x12 and os.path.exists(first["joints"]["j2"]["console"])
    assert cli.main(["sim", "--json"]) == 0
    again = json.loads(capsys.readouterr().out)
    assert not again["started"] and again["pid"] == first["pid"], "one arm: a second start finds it"
    assert cli.main(["sim", "stop"]) == 0
    assert f"stopped the simulated arm (pid {first['pid']})" in capsys.readouterr().out
    assert not (state_dir / "sim.sock").exists() and sim_service.status(state_dir) is None
    assert cli.main(["sim", "stop"]) == 0 and "no simulated arm was running" in capsys.readouterr().out


def test_files_are_private(state_dir: Path) -> None:
    assert sim_service.start(state_dir, SPECS, idle_exit_s=IDLE_EXIT_S)
    assert stat.S_IMODE(state_dir.stat().st_mode) == 0o700
    for name in ("sim.sock", "sim.lock", "sim.log"):
        assert stat.S_IMODE((state_dir / name).stat().st_mode) == 0o600, name


def test_concurrent_starts_run_one_arm(state_dir: Path) -> None:
    results: list[bool] = []
    threads = [threading.Thread(target=lambda: results.append(sim_service.start(state_dir, SPECS, idle_exit_s=IDLE_EXIT_S)))
               for _ in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=30)
    assert sorted(results) == [False, False, False, True]
    status = sim_service.status(state_dir)
    assert status is not None
    assert int((state_dir / "sim.lock").read_text()) == status["pid"]


def test_a_stale_socket_and_a_crashed_service_do_not_block_the_next_start(state_dir: Path) -> None:
    state_dir.mkdir(parents=True, mode=0o700)
    stale = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    stale.bind(str(state_dir / "sim.sock"))  # left behind: nobody listens on it
    stale.close()
    assert sim_service.start(state_dir, SPECS, idle_exit_s=IDLE_EXIT_S)
    bus = ServiceBus(SPECS, state_dir, idle_exit_s=IDLE_EXIT_S)
    assert bus.scan() == [0x11, 0x12, 0x13, 0x14]
    pid = sim_service.status(state_dir)["pid"]  # type: ignore[index]
    os.kill(pid, signal.SIGKILL)
    assert wait_until(lambda: sim_service.status(state_dir) is None)
    with pytest.raises(CommError, match="not running"):
        bus.scan()  # the arm is gone: this client is told, it does not start a new one by itself
    assert sim_service.start(state_dir, SPECS, idle_exit_s=IDLE_EXIT_S), "the lock died with the service"
    assert bus.scan() == [0x11, 0x12, 0x13, 0x14], "the client reconnects"
    bus.close()


def test_another_configuration_is_refused_until_the_arm_is_stopped(state_dir: Path) -> None:
    sim_service.start(state_dir, SPECS, idle_exit_s=IDLE_EXIT_S)
    other = [replace(spec, address=spec.address + 0x10) for spec in SPECS]
    with pytest.raises(ConfigError, match="bioscara sim stop"):
        ServiceBus(other, state_dir, idle_exit_s=IDLE_EXIT_S)
    sim_service.stop(state_dir)
    ServiceBus(other, state_dir, idle_exit_s=IDLE_EXIT_S).close()


def test_a_client_speaking_garbage_is_hung_up_on_and_others_are_served(state_dir: Path) -> None:
    sim_service.start(state_dir, SPECS, idle_exit_s=IDLE_EXIT_S)
    bus = ServiceBus(SPECS, state_dir, idle_exit_s=IDLE_EXIT_S)
    rogue = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    rogue.settimeout(5.0)
    rogue.connect(str(state_dir / "sim.sock"))
    rogue.sendall(b"\xff\xff\xff\xff" + b"\x00" * 64)
    assert rogue.recv(16) == b"", "hung up"
    rogue.close()
    assert bus.transfer(0x11, bytes([0x0F]), 2)[0] == ord("O"), "PING answered"
    bus.close()


def test_an_unused_arm_ends_by_itself_a_client_or_a_moving_joint_keeps_it(state_dir: Path) -> None:
    """An aborted script or test run leaves nothing running for long: the service ends after its
    idle exit (here 1 s) without a client and with every joint at rest, not before."""
    assert sim_service.start(state_dir, SPECS, idle_exit_s=1.0)
    socket_file = state_dir / "sim.sock"
    bus = ServiceBus(SPECS, state_dir, autostart=False)
    joint = make_joint(read_config().joints["j1"], bus)
    joint.init()
    time.sleep(2.0)  # twice the idle exit
    assert socket_file.exists(), "a connected client keeps it"
    joint.enable(50, 30)
    joint.move_steps(10_000)  # about 4 s at the speed SETUP leaves; the original deadman lets it run
    joint.close()
    bus.close()
    time.sleep(2.0)
    assert socket_file.exists(), "a joint that still moves keeps it"
    assert sim_service.status(state_dir)["moving"] == ["j1"]  # type: ignore[index]
    assert wait_until(lambda: not socket_file.exists(), timeout=30.0), "ended once the joint came to rest"
    assert "idle for" in (state_dir / "sim.log").read_text()
    assert sim_service.status(state_dir) is None


def test_the_idle_exit_comes_from_the_configuration_or_the_command(
        state_dir: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv("BIOSCARA_SIM_IDLE_EXIT", "2.5")
    assert cli.main(["sim", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["idle_exit_s"] == 150.0
    assert cli.main(["sim", "stop"]) == 0
    assert cli.main(["sim", "start", "--idle-exit", "0"]) == 0
    assert "without a client" not in capsys.readouterr().out, "0: never"
    assert cli.main(["sim", "status", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["idle_exit_s"] is None
    assert cli.main(["sim", "start", "--idle-exit", "3"]) == 0
    assert "already running" in capsys.readouterr().err, "not silently ignored"
    assert cli.main(["sim", "status", "--idle-exit", "3"]) == 2
    assert cli.main(["sim", "--pty", "--idle-exit", "3"]) == 2
    monkeypatch.setenv("BIOSCARA_SIM_IDLE_EXIT", "soon")
    assert cli.main(["sim", "start"]) == 2
    assert "BIOSCARA_SIM_IDLE_EXIT" in capsys.readouterr().err


class _WallClock:
    """The server's wall clock, moved by the test: what the server does with the time that passes
    is then exact, however long this machine takes to run it."""

    def __init__(self) -> None:
        self.now = 0.0

    def monotonic(self) -> float:
        return self.now


class _Probe:
    """A frontend with nothing connected: notes the simulated and the wall clock when a byte arrives."""

    def __init__(self, server: SimServer, wall: _WallClock) -> None:
        self.server = server
        self.wall = wall
        self.inside, self.outside = socket.socketpair()
        self.inside.setblocking(False)
        self.first: tuple[int, float] | None = None
        self.seen: tuple[int, float] | None = None
        self.waits_at = -1  # simulated time (us) at which the server last went to wait for input

    def fds(self) -> list[int]:
        self.waits_at = self.server.clock.now_us  # asked right before the server waits for input
        return [self.inside.fileno()]

    def busy(self) -> bool:
        return False

    def poll(self) -> None:
        now = (self.server.clock.now_us, self.wall.monotonic())
        if self.first is None:
            self.first = now
        try:
            if self.inside.recv(1):
                self.seen = now
        except BlockingIOError:
            pass


def test_at_rest_the_joints_follow_the_wall_clock_and_input_finds_them_caught_up(
        monkeypatch: pytest.MonkeyPatch) -> None:
    from bioscara import sim_server

    wall = _WallClock()
    monkeypatch.setattr(sim_server, "time", wall)
    server = SimServer(SPECS)
    probe = _Probe(server, wall)
    server.add_frontend(probe)
    with server:
        assert wait_until(lambda: probe.first is not None)
        assert probe.first is not None
        start_us = probe.first[0]
        # The wall clock moves only while the server waits for input, as it would at rest.
        assert wait_until(lambda: probe.waits_at >= start_us)
        for _ in range(3):  # steps shorter than a long wait at rest: no input, so nothing wakes the server
            wall.now += 0.2
            target = start_us + round(wall.now * 1e6)
            assert wait_until(lambda: probe.waits_at >= target), "at rest, it follows the wall clock"
        assert not server.moving()
        wall.now += 0.1  # then input, a moment into the next long wait
        probe.outside.send(b"x")
        assert wait_until(lambda: probe.seen is not None)
    assert probe.seen is not None
    simulated = (probe.seen[0] - probe.first[0]) / 1e6
    assert probe.seen[1] == pytest.approx(0.7) and simulated == pytest.approx(0.7, abs=1e-6), \
        "served at the wall clock, not a wait behind"


def test_a_joints_configuration_file_is_replaced_whole_and_read_at_its_reboot(state_dir: Path) -> None:
    bus = ServiceBus(SPECS, state_dir, idle_exit_s=IDLE_EXIT_S)
    try:
        data = json.loads(bus.joint_config_file(0x13))
        assert data["joint"] == "J3" and "encoder" not in data
        with pytest.raises(ConfigError, match="encoder.correction must be a list of 16, 32 or 64 integers"):
            bus.write_joint_config_file(0x13, json.dumps(dict(data, encoder={"correction": [1, 2, 3]})).encode())
        assert "encoder" not in json.loads(bus.joint_config_file(0x13)), "a refused file changes nothing"
        table = [(i * 37) % 101 - 50 for i in range(16)]
        bus.write_joint_config_file(0x13, json.dumps(dict(data, encoder={"correction": table})).encode())
        assert json.loads(bus.joint_config_file(0x13))["encoder"] == {"correction": table}
        bus.reboot_joint(0x13)
        joint = make_joint(read_config().joints["j3"], bus, False)
        joint.init()
        assert not joint.is_homed(), "the joint booted again"
        (zero,) = joint.read_register("ENCODERZERO")
        assert 0.0 <= zero < 360.0
        joint.close()
        with pytest.raises(ConfigError, match="no simulated joint at that address"):
            bus.joint_config_file(0x30)
    finally:
        bus.close()
