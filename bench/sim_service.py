"""The shared simulated arm (`sim:`, bioscara.sim_service) at rest: its CPU with no client, and
with one client connected that sends nothing (a shell or script between commands). Every joint's
firmware still runs each tick in real time; what the service saves at rest is the turns between
them (one wait of up to 0.25 s instead of one per millisecond). Prints `name value` lines (% of
one core over WINDOW_S of wall time); `make bench` runs it."""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

from bioscara import sim_service
from bioscara.config import read_config
from bioscara.hardware import sim_joint_specs

WINDOW_S = 10.0
SETTLE_S = 1.0  # after starting, and after a client connects


def _cpu_s(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as stat:
        fields = stat.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _share(pid: int) -> float:
    """% of one core the process used over WINDOW_S."""
    cpu, wall = _cpu_s(pid), time.monotonic()
    time.sleep(WINDOW_S)
    return 100.0 * (_cpu_s(pid) - cpu) / (time.monotonic() - wall)


def main() -> None:
    specs = sim_joint_specs(read_config())
    with tempfile.TemporaryDirectory(prefix="bioscara-bench-") as home:
        state_dir = Path(home) / "bioscara"
        sim_service.start(state_dir, specs, idle_exit_s=None)
        try:
            status = sim_service.status(state_dir)
            assert status is not None
            pid = status["pid"]
            time.sleep(SETTLE_S)
            idle = _share(pid)
            bus = sim_service.ServiceBus(specs, state_dir, autostart=False)
            try:
                time.sleep(SETTLE_S)
                connected = _share(pid)
            finally:
                bus.close()
        finally:
            sim_service.stop(state_dir)
    print(f"sim_service.idle_cpu_percent {idle:.1f}")
    print(f"sim_service.idle_client_cpu_percent {connected:.1f}")


if __name__ == "__main__":
    sys.exit(main())
