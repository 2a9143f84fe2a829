"""The serial transport through a real pseudo-terminal to the simulator server (real time).

The host side is the production path: `serial:<pty>` -> SerialBus (pyserial) -> bridge framing ->
the bridge firmware -> simulated joints running the joint firmware.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import replace

import pytest

from bioscara.arm import make_joint
from bioscara.transports import open_bus
from bioscara.bus.serial import SerialBus
from bioscara.config import ArmConfig, read_config
from bioscara.errors import CommError, ConfigError
from bioscara.firmware.spec import protocol as P
from bioscara.hardware import sim_joint_specs
from bioscara.hil_bridge import framing as F
from bioscara.joint import Joint
from bioscara.sim_server import Pty, SimServer


@pytest.fixture
def config() -> ArmConfig:
    """The shipped arm, each joint starting just inside the end stop it homes into (real time: short)."""
    config = read_config()
    start = {}
    for name, jc in config.joints.items():
        margin = 0.02 if jc.type == "revolute" else 0.001  # rad, m
        start[name] = jc.max - margin if jc.homing.direction > 0 else jc.min + margin
    return replace(config, sim=replace(config.sim, start=start))


@pytest.fixture
def server(config: ArmConfig) -> Iterator[SimServer]:
    # The host side of these tests runs in this process, next to the server: on a loaded machine it
    # can be held up longer than the joints' 50 ms deadman, which is not what these tests are about.
    specs = [replace(spec, deadman_ms=500) for spec in sim_joint_specs(config)]
    with SimServer(specs, seed=config.sim.seed) as server:
        yield server


@pytest.fixture
def bus(server: SimServer) -> Iterator[SerialBus]:
    # The server shares this process (and its GIL) with the host: a longer wait per attempt than
    # a USB bridge needs, so a loaded machine does not turn into lost transfers here.
    bus = open_bus(f"serial:{server.bridge_path}?timeout=0.1")
    assert isinstance(bus, SerialBus)
    yield bus
    bus.close()


def wait_until(condition, timeout: float, period: float = 0.02) -> bool:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(period)
    return True


def test_the_joint_api_round_trip_on_four_joints(config: ArmConfig, bus: SerialBus) -> None:
    joints = [make_joint(jc, bus) for jc in config.joints.values()]
    for joint in joints:
        joint.init()
        assert joint.identity().spec_matches
        joint.enable(joint_config(config, joint).drive_current, joint_config(config, joint).hold_current)
        assert joint.is_enabled() and not joint.is_homed()
    for joint in joints:
        homing = joint_config(config, joint).homing
        joint.set_max_acceleration(joint_config(config, joint).max_acceleration)
        joint.start_homing(homing.direction * homing.speed, homing.threshold, homing.current)
    for joint in joints:
        joint.wait_while_busy(0.05, timeout=30.0)  # real time, on a loaded machine too
        joint.post_homing()
        assert joint.is_homed()
    targets = {}
    for joint in joints:
        jc = joint_config(config, joint)
        inward = 0.2 if jc.type == "revolute" else 0.01  # rad or m away from the end stop homed on
        targets[joint.name] = joint.get_position() - jc.homing.direction * inward
        joint.set_max_velocity(jc.max_velocity)
        joint.set_position(targets[joint.name])
    def settled(joint: Joint) -> bool:
        jc = joint_config(config, joint)
        return (abs(joint.get_position() - targets[joint.name]) < tolerance(config, joint)
                and abs(joint.get_velocity()) < 0.05 * jc.max_velocity)

    # Every joint is read every turn: the firmware's deadman stops a joint the host is silent to.
    assert wait_until(lambda: all([settled(joint) for joint in joints]), timeout=10.0)
    for joint in joints:
        joint.disable()
    assert bus.link.timeouts == 0 and bus.link.resyncs == 0


def joint_config(config: ArmConfig, joint: Joint):
    return config.joints[joint.name]


def tolerance(config: ArmConfig, joint: Joint) -> float:
    return 0.002 if joint_config(config, joint).type == "prismatic" else 0.02


def test_scan_version_and_nack(bus: SerialBus) -> None:
    assert bus.scan() == [0x11, 0x12, 0x13, 0x14]
    assert bus.version.protocol == F.PROTOCOL and bus.version.i2c_hz == 400_000
    with pytest.raises(CommError, match="NACK"):
        bus.transfer(0x42, bytes([P.PING]), 2)
    assert bus._probe(0x11) and not bus._probe(0x42)
    assert bus.stats.link(0x42).comm_errors == 1


class Meddler:
    """A man in the middle between the host and the server's pty, corrupting what the server says.

    `mangle(frame) -> bytes` decides what the host receives instead of each answer frame.
    """

    def __init__(self, server_path: str) -> None:
        import serial
        self.upstream = serial.Serial(server_path, timeout=0.01)
        self.pty = Pty()
        self.path = self.pty.path
        self.mangle = lambda frame: frame
        self.mangle_up: Callable[[bytes], bytes] = lambda data: data  # what the host sends
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        import select
        buf = bytearray(256)
        parser = F.FrameParser()
        while not self._stop.is_set():
            select.select([self.pty, self.upstream], [], [], 0.01)
            n = self.pty.readinto(buf)
            if n:
                self.upstream.write(self.mangle_up(bytes(buf[:n])))
            data = self.upstream.read(self.upstream.in_waiting)
            pos = 0
            while True:
                pos = parser.feed(data, pos)
                if not parser.ready:
                    break
                self.pty.write(self.mangle(bytes(parser.buf[:parser.size])))
                parser.release()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.upstream.close()
        self.pty.close()


@pytest.fixture
def meddler(server: SimServer) -> Iterator[Meddler]:
    meddler = Meddler(server.bridge_path)
    yield meddler
    meddler.close()


def test_garbage_truncation_and_bit_flips_are_survived_without_wrong_data(meddler: Meddler) -> None:
    bus = open_bus(f"serial:{meddler.path}", attempts=6)
    joint = Joint("j1", 0x11, bus)
    joint.init()
    count = 0

    def nasty(frame: bytes) -> bytes:
        nonlocal count
        count += 1
        if count % 4 == 1:
            flipped = bytearray(frame)
            flipped[count % len(frame)] ^= 1 << (count % 8)
            return bytes(flipped)  # a bit flip: the CRC catches it, the attempt is retried at once
        if count % 4 == 2:
            return frame[:len(frame) // 2]  # truncated: dropped after a quiet spell
        if count % 4 == 3:
            return b"\xa5\x05\x13\x37\xa5\x00\xff\x10\x42\x0a" + frame  # garbage, then the answer
        return frame

    meddler.mangle = nasty
    for _ in range(6):
        (degrees,) = joint.read_register("ANGLEMOVED")
        assert math.isfinite(degrees) and abs(degrees) < 10.0
        assert joint.identity().spec_matches, "every answer decoded is the right register's"
    link = bus.link
    assert link.crc_errors > 0 and link.truncated > 0 and link.skipped_bytes > 0
    assert link.damaged > 0 and link.timeouts == 0, "no damaged answer is waited out"
    assert bus.stats.link(0x11).comm_errors == 0
    bus.close()


def test_one_damaged_byte_never_faults_the_arm(config: ArmConfig) -> None:
    """A byte damaged on the serial link, in either direction, is retried and never faults the arm.

    What proves a damaged answer is not waited out is that every one was given up at once
    (`damaged`); a damaged request has no answer, so it costs one attempt's timeout. The times are
    generous because they are not what is tested: the simulator, the meddler and the host share
    this process, and on a loaded machine a round trip through them can take longer than the 50 ms
    a USB bridge needs by far, and the host can be held up for longer than the joints' 50 ms
    deadman and 100 ms watchdog (a real joint would stop then, as it should).
    """
    import random

    from bioscara import motion
    from bioscara.arm import Arm
    from bioscara.communicator import Communicator

    rng = random.Random(12)
    specs = [replace(spec, deadman_ms=1000) for spec in sim_joint_specs(config)]
    config = replace(config, joints={name: replace(joint, watchdog_ms=3000) for name, joint in config.joints.items()})
    damaged = {"down": 0, "up": 0}

    def damage(direction: str, every: int) -> Callable[[bytes], bytes]:
        count = 0

        def mangle(data: bytes) -> bytes:
            nonlocal count
            count += 1
            if count % every or damaged[direction] >= 40:
                return data
            damaged[direction] += 1
            out = bytearray(data)
            out[rng.randrange(len(out))] ^= rng.randrange(1, 256)
            return bytes(out)
        return mangle

    with SimServer(specs, seed=config.sim.seed) as server:
        meddler = Meddler(server.bridge_path)
        bus = open_bus(f"serial:{meddler.path}?timeout=0.25", attempts=10)  # a loaded machine may hold an answer past several
        try:
            arm = Arm(config, bus)
            arm.configure()
            arm.activate()
            comm = Communicator(arm, frequency=100.0, realtime_priority=None)
            motion.home(arm, comm, timeout=20.0)
            # Turning slowly away from the end stops: the deadman stops a joint in motion.
            arm.switch_modes(start=[f"{name}/velocity" for name in arm.joints])
            for name, aj in arm.joints.items():
                arm.set_command(name, "velocity", -aj.config.homing.direction * 0.02 * aj.config.max_velocity)
            meddler.mangle, meddler.mangle_up = damage("down", 5), damage("up", 7)
            comm.run_until(lambda: min(damaged.values()) >= 40, timeout=60.0)
            meddler.mangle = meddler.mangle_up = lambda data: data
            comm.run_until(lambda: False, timeout=0.3, raise_on_timeout=False)
            assert arm.fault is None and all(aj.joint.is_enabled() for aj in arm.joints.values())
            assert all(abs(aj.state.velocity) > 0 for aj in arm.joints.values()), "still turning"
            assert sum(link.comm_errors for link in bus.stats.links.values()) == 0
            assert bus.link.damaged == damaged["down"], "every damaged answer was retried at once"
            arm.deactivate()
        finally:
            bus.close()
            meddler.close()


def test_a_late_answer_to_an_earlier_transfer_is_discarded(meddler: Meddler) -> None:
    bus = open_bus(f"serial:{meddler.path}?timeout=0.05", attempts=1)
    held: list[bytes] = []

    def hold_the_first(frame: bytes) -> bytes:
        if not held:
            held.append(frame)
            return b""  # the first transfer's answer comes only with the next transfer's
        return held.pop() + frame if held else frame

    meddler.mangle = hold_the_first
    with pytest.raises(CommError):
        bus.transfer(0x11, bytes([P.PING]), 2)
    reply = bus.transfer(0x11, bytes([P.IDENTITY]), P.register("IDENTITY").rsize + 1)
    assert P.register("IDENTITY").decode(reply[:-1])[5] == P.SPEC_HASH, "not the PING's answer"
    assert bus.link.stale == 1
    bus.close()


def test_a_retry_after_a_lost_answer_does_not_run_the_command_twice(server: SimServer, meddler: Meddler) -> None:
    bus = open_bus(f"serial:{meddler.path}?timeout=0.1")
    joint = Joint("j1", 0x11, bus, reduction=35.0)
    joint.init()
    joint.enable(20, 20)
    dropped: list[bytes] = []

    def drop_once(frame: bytes) -> bytes:
        if not dropped:
            dropped.append(frame)
            return b""
        return frame

    meddler.mangle = drop_once
    joint.start_homing(-0.03, 30, 15)  # a second HOME would be rejected as already running
    meddler.mangle = lambda frame: frame
    assert server.bridge.replays == 1 and bus.link.timeouts == 1
    assert joint.last_reject().count == 0, "the joint saw one HOME"
    bus.close()


def test_missing_busy_and_wrong_ports_give_one_clear_line(server: SimServer, tmp_path) -> None:
    with pytest.raises(CommError, match="does not exist"):
        open_bus(f"serial:{tmp_path}/ttyNOPE")
    first = open_bus(f"serial:{server.bridge_path}")
    with pytest.raises(CommError, match="busy"):
        open_bus(f"serial:{server.bridge_path}")
    first.close()
    with pytest.raises(CommError, match="no HIL bridge answers"):
        open_bus(f"serial:{server.joint_paths['J1']}?timeout=0.02")
    with pytest.raises(ConfigError, match="unknown option"):
        open_bus(f"serial:{server.bridge_path}?speed=3")
    with pytest.raises(ConfigError, match="not a number"):
        open_bus(f"serial:{server.bridge_path}?baud=fast")


def test_transactions_per_second_through_the_pty(bus: SerialBus) -> None:
    ping = bytes([P.PING])
    start = time.perf_counter()
    n = 0
    while time.perf_counter() - start < 0.3:
        assert bus.transfer(0x11, ping, 2)[0] == P.ACK
        n += 1
    rate = n / (time.perf_counter() - start)
    print(f"{rate:.0f} transactions/s through the pty")
    assert rate > 200


def test_the_sim_command_prints_its_paths_and_stops_cleanly_on_ctrl_c() -> None:
    proc = subprocess.Popen([sys.executable, "-m", "bioscara.cli", "sim", "--pty", "--json"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        paths = json.loads(proc.stdout.readline())  # type: ignore[union-attr]
        assert sorted(paths["joints"]) == ["j1", "j2", "j3", "j4"]
        assert all(os.path.exists(p) for p in [paths["bridge"], *paths["joints"].values()])
        bus = open_bus(f"serial:{paths['bridge']}")
        assert bus.scan() == [0x11, 0x12, 0x13, 0x14]
        bus.close()
    finally:
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=10)
    assert proc.returncode == 0 and err == ""


def test_ports_says_which_port_is_the_bridge_and_which_a_joint(server: SimServer, tmp_path, capsys) -> None:
    from bioscara import cli
    plain = Pty()  # a terminal nothing answers on
    try:
        code = cli.main(["ports", "--json", server.bridge_path, server.joint_paths["J2"], plain.path,
                         str(tmp_path / "ttyACM5")])
        found = {e["port"]: e for e in json.loads(capsys.readouterr().out)}
    finally:
        plain.close()
    assert code == 0
    assert found[server.bridge_path]["kind"] == "HIL bridge" and found[server.bridge_path]["use"].startswith("--bus")
    assert found[server.joint_paths["J2"]]["kind"] == "joint debug port"
    assert found[server.joint_paths["J2"]]["detail"] == "j2 at 0x12"
    assert found[plain.path]["kind"] == "unknown"
    assert found[str(tmp_path / "ttyACM5")]["kind"] == "unavailable"
