"""Host benchmarks on the simulated bus (CPython): control-cycle cost and communicator rates.

The simulator runs inside the same process, so the time spent in it (the firmware and physics of
four joints) is measured separately and subtracted: "host" is the bioscara stack alone.
"""

from __future__ import annotations

import time
from dataclasses import replace

from bioscara import motion
from bioscara.bus.sim import SimBus
from bioscara.communicator import Communicator
from bioscara.config import read_config
from bioscara.hardware import open_arm, open_arm_bus


class SimMeter:
    """Accumulates the CPU time spent inside the simulator's own calls."""

    def __init__(self, bus: SimBus) -> None:
        self.seconds = 0.0
        self._depth = 0  # transfer() calls run_until(): time only the outermost call
        for name in ("transfer", "run_until"):
            original = getattr(bus.sim, name)
            setattr(bus.sim, name, self._timed(original))

    def _timed(self, function):  # type: ignore[no-untyped-def]
        def timed(*args, **kwargs):  # type: ignore[no-untyped-def]
            self._depth += 1
            t0 = time.process_time()
            try:
                return function(*args, **kwargs)
            finally:
                self._depth -= 1
                if self._depth == 0:
                    self.seconds += time.process_time() - t0
        return timed


def homed_arm(realtime: bool = False, protocol: str = "auto"):  # type: ignore[no-untyped-def]
    config = read_config()
    config = replace(config, bus=replace(config.bus, url="sim:realtime" if realtime else "sim:virtual"))
    bus = open_arm_bus(config)
    arm = open_arm(config, bus, protocol)
    arm.configure()
    arm.activate()
    motion.home(arm, Communicator(arm, 100.0, realtime_priority=None), timeout=120)
    arm.switch_modes(start=[f"{name}/position" for name in arm.joints])
    return arm, bus


def control_cycle(cycles: int = 2000, protocol: str = "legacy") -> dict[str, float]:
    """One 4-joint position-mode cycle, back to back with 1 ms of simulated time between cycles
    (the joints' main loop runs, as at any cycle rate up to 1 kHz): wire bits and host CPU."""
    arm, bus = homed_arm(protocol=protocol)
    meter = SimMeter(bus)
    bits0, stretch0 = bus.sim.bits, bus.sim.stretch_us
    t0 = time.process_time()
    for _ in range(cycles):
        arm.cycle()
        bus.sleep(0.001)
    total = time.process_time() - t0
    host = (total - meter.seconds) / cycles
    bits = (bus.sim.bits - bits0) / cycles
    wire = bits / bus.speed_hz
    stretch = (bus.sim.stretch_us - stretch0) / cycles * 1e-6
    return {"host_us": host * 1e6, "sim_us": meter.seconds / cycles * 1e6, "bits": bits,
            "wire_us": wire * 1e6, "fraction": host / wire, "bus_us": (wire + stretch) * 1e6}


def communicator_virtual(rate: float, seconds: float = 5.0) -> dict[str, float]:
    arm, bus = homed_arm()
    meter = SimMeter(bus)
    comm = Communicator(arm, rate, realtime_priority=None)
    t0 = time.process_time()
    comm.run_for(seconds)
    cpu = time.process_time() - t0
    s = comm.stats
    return {"rate": s.rate, "jitter_us": s.jitter * 1e6, "overruns": s.overruns, "cycles": s.cycles,
            "host_share": (cpu - meter.seconds) / seconds, "sim_share": meter.seconds / seconds}


def communicator_realtime(rate: float, seconds: float = 3.0) -> dict[str, float]:
    arm, bus = homed_arm(realtime=True)
    meter = SimMeter(bus)
    comm = Communicator(arm, rate)
    t0, c0 = time.monotonic(), time.process_time()
    comm.start()
    time.sleep(seconds)
    comm.stop()
    wall, cpu = time.monotonic() - t0, time.process_time() - c0
    s = comm.stats
    return {"rate": s.rate, "jitter_us": s.jitter * 1e6, "overruns": s.overruns, "cycles": s.cycles,
            "host_share": (cpu - meter.seconds) / wall, "sim_share": meter.seconds / wall,
            "scheduling": comm.scheduling}


def bridge_throughput(transactions: int = 2000) -> dict[str, float]:
    """PING transactions per second through the HIL bridge framing on the simulator's pty."""
    from bioscara.transports import open_bus
    from bioscara.firmware.spec import protocol as P
    from bioscara.hardware import sim_joint_specs
    from bioscara.sim_server import SimServer

    with SimServer(sim_joint_specs(read_config())) as server:
        bus = open_bus(f"serial:{server.bridge_path}")
        t0 = time.perf_counter()
        for _ in range(transactions):
            bus.transfer(0x11, bytes([P.PING]), 2)
        seconds = time.perf_counter() - t0
        bus.close()
    return {"per_s": transactions / seconds, "us": seconds / transactions * 1e6}
