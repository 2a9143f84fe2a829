"""The fixed-rate communicator: timing in virtual time, overruns, subscribers, thread control."""

from __future__ import annotations

import logging
import os
import time

import pytest

from bioscara import motion
from bioscara.arm import Arm
from bioscara.bus.sim import SimBus
from bioscara.communicator import Communicator
from bioscara.firmware.spec import protocol as P


def _transaction_s(bus: SimBus, name: str, command: bool) -> float:
    """One 75-bit-time transaction at 400 kHz plus the clock stretching the joint chip shows for
    it (the simulator's cost table, measured by make bench-chip)."""
    return 75 / 400_000 + bus.sim.chip.scl_held_us(P.register(name).addr, command) * 1e-6


def _v2_cycle_s(bus: SimBus) -> float:
    """A 4-joint v2 cycle: one 156-bit transaction per joint, the clock held only while the
    peripheral's C code serves the memory (the cost table's figure)."""
    return 4 * (156 / 400_000 + bus.sim.chip.mem_held_us * 1e-6)


def _cycle_s(bus: SimBus, writes: bool) -> float:
    """A 4-joint cycle: ANGLEMOVED and GETENCODERRPM reads per joint, plus MOVETOANGLE if writing."""
    per_joint = _transaction_s(bus, "ANGLEMOVED", False) + _transaction_s(bus, "GETENCODERRPM", False)
    if writes:
        per_joint += _transaction_s(bus, "MOVETOANGLE", True)
    return 4 * per_joint


def test_cycles_run_at_the_configured_rate_in_virtual_time(arm: Arm, bus: SimBus) -> None:
    arm.configure()
    comm = Communicator(arm, frequency=100.0, realtime_priority=None)
    t0 = bus.monotonic()
    comm.run_for(2.0)
    stats = comm.stats
    assert stats.cycles == pytest.approx(200, abs=1)
    assert stats.rate == pytest.approx(100.0, rel=1e-6) and stats.jitter < 1e-6
    assert stats.overruns == 0 and stats.errors == 0
    # Inactive (no commands): legacy 4 joints x 2 register reads, wire time plus the chip's clock
    # stretching; v2 one 156-bit transaction per joint (its mailbox carries NONE), served from memory.
    expected = _v2_cycle_s(bus) if arm.protocol == "v2" else _cycle_s(bus, writes=False)
    assert stats.duration_mean == pytest.approx(expected, rel=0.02)
    assert bus.monotonic() - t0 == pytest.approx(2.0, abs=0.011)


def test_a_slow_cycle_is_counted_as_an_overrun(arm: Arm, bus: SimBus) -> None:
    arm.configure()
    comm = Communicator(arm, frequency=100.0, realtime_priority=None)
    comm.run_for(0.1)
    cycle = arm.cycle

    def slow_cycle() -> None:
        cycle()
        bus.sleep(0.015)  # longer than the 10 ms period
    arm.cycle = slow_cycle  # type: ignore[method-assign]
    comm.run_for(0.1)
    assert comm.stats.overruns >= 3
    assert comm.stats.duration_max >= 0.015 and comm.stats.period_max >= 0.015


def test_the_bus_limits_the_rate_with_four_joints_at_500_hz(arm: Arm, bus: SimBus) -> None:
    arm.configure()
    arm.activate()
    motion.home(arm, Communicator(arm, frequency=100.0, realtime_priority=None))
    arm.switch_modes(start=[f"{name}/position" for name in arm.joints])
    comm = Communicator(arm, frequency=500.0, realtime_priority=None)
    comm.run_for(0.5)
    if arm.protocol == "legacy":
        # A 4-joint cycle with writes needs 4 x 225 bit times = 2.25 ms of wire at 400 kHz, plus the
        # chip's clock stretching: far more than 2 ms.
        cycle = _cycle_s(bus, writes=True)
        assert cycle > 4 * 225 / 400_000
        assert comm.stats.overruns == comm.stats.cycles
        assert comm.stats.rate == pytest.approx(1 / cycle, rel=0.02)
    else:
        # v2: 4 x 156 bit times = 1.56 ms of wire (a 641 Hz ceiling), plus the chip's ~14 us per
        # transaction: 500 Hz fits.
        # (the first cycle also refreshes the flags, older than 20 ms after the homing, with a poll
        # each; one joint's state in it then acknowledges that poll, not the setpoint: its flags
        # are refreshed once more in the second)
        assert comm.stats.overruns <= 2 and comm.stats.rate == pytest.approx(500.0, rel=0.01)
        assert comm.stats.duration_mean == pytest.approx(_v2_cycle_s(bus), rel=0.02)


def test_snapshots_reach_subscribers_and_a_slow_one_never_blocks_the_loop(arm: Arm) -> None:
    arm.configure()
    comm = Communicator(arm, frequency=100.0, realtime_priority=None)
    fast, slow = comm.subscribe(), comm.subscribe(maxlen=5)
    comm.run_for(0.2)
    got = fast.drain()
    cycles = comm.stats.cycles
    assert cycles >= 20 and [s.cycle for s in got] == list(range(1, cycles + 1))
    assert set(got[-1].values()) >= {"j1/position", "j1/velocity", "j1/flags", "j2/home"}
    assert [s.cycle for s in slow.drain()] == list(range(cycles - 4, cycles + 1)) and slow.dropped == cycles - 5
    assert fast.get(timeout=0) is None


def test_link_health_counts_failures_per_joint(arm: Arm, bus: SimBus) -> None:
    arm.configure()
    comm = Communicator(arm, frequency=100.0, realtime_priority=None)
    comm.run_for(0.1)
    joint = bus.joint(0x12)
    joint.connected = False  # j2's cable comes off
    comm.run_for(0.05, stop_on_fault=False)
    health = comm.link_health()
    assert health["j2"]["comm_errors"] >= 1 and "NACK" in str(health["j2"]["last_error"])
    assert health["j1"]["comm_errors"] == 0 and health["j1"]["transactions"] > 0
    assert comm.stats.errors >= 1


def test_start_stop_restart_of_the_loop_thread(arm: Arm) -> None:
    arm.configure()
    comm = Communicator(arm, frequency=200.0, realtime_priority=None)
    comm.start()
    assert comm.running
    comm.run_until(lambda: comm.stats.cycles >= 20, timeout=30.0)
    comm.stop()
    assert not comm.running
    cycles = comm.stats.cycles
    time.sleep(0.05)
    assert comm.stats.cycles == cycles, "no cycles after stop"
    comm.restart()
    comm.run_until(lambda: comm.stats.cycles >= cycles + 10, timeout=30.0)
    comm.stop()


def test_scheduling_falls_back_with_a_clear_message(arm: Arm, monkeypatch: pytest.MonkeyPatch,
                                                   caplog: pytest.LogCaptureFixture) -> None:
    def refuse(*args: object) -> None:
        raise PermissionError(1, "Operation not permitted")
    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    comm = Communicator(arm, frequency=100.0, realtime_priority=50)
    with caplog.at_level(logging.WARNING):
        comm._set_scheduling()
    assert comm.scheduling == "normal"
    assert "SCHED_FIFO" in caplog.text and "not permitted" in caplog.text


def test_bad_frequencies_are_refused(arm: Arm) -> None:
    for frequency in (0.0, -5.0, 1e6):
        with pytest.raises(ValueError):
            Communicator(arm, frequency=frequency)


def test_a_restart_does_not_count_the_pause_as_a_period(arm: Arm) -> None:
    arm.configure()
    comm = Communicator(arm, frequency=200.0, realtime_priority=None)
    comm.start()
    comm.run_until(lambda: comm.stats.cycles >= 20, timeout=30.0)
    comm.stop()
    time.sleep(0.3)
    comm.start()
    comm.run_until(lambda: comm.stats.cycles >= 40, timeout=30.0)
    comm.stop()
    assert comm.stats.period_max < 0.25, "the 0.3 s pause is not a cycle period"
