"""Benchmarks, measured side by side in one run. `make bench` runs this.

Firmware (MicroPython unix port): IRQ-path time per transaction as a fraction of its wire time at
400 kHz, main-loop iteration time, simulated-joint speed. The same simulated-joint figure is also
measured under CPython, where the host's simulator runs it.
"""

from __future__ import annotations

import os
import pathlib
import shutil
import subprocess
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "firmware"), str(ROOT / "firmware" / "tests"), str(ROOT / "bench"),
                str(ROOT / "tests")]


def micropython_figures() -> dict[str, float]:
    binary = shutil.which("micropython") or str(pathlib.Path(sys.executable).parent / "micropython")
    env = dict(os.environ, MICROPYPATH=f"{ROOT / 'firmware'}:{ROOT / 'firmware' / 'tests'}:{ROOT / 'bench'}")
    out = subprocess.run([binary, "-X", "heapsize=8M", str(ROOT / "bench" / "firmware_irq.py")],
                         capture_output=True, text=True, env=env, check=True).stdout
    return {name: float(value) for name, value in (line.split() for line in out.splitlines() if line.strip())}


def main() -> None:
    mp = micropython_figures()
    print("firmware, MicroPython unix port on this machine")
    for label, frame in (("read_float", "register read of a float (75 bit times)"),
                         ("command_float", "command with a float payload (75 bit times)")):
        print(f"  IRQ path, {frame}: {mp['irq_us_' + label]:.1f} us per transaction = "
              f"{mp['irq_fraction_of_wire_' + label] * 100:.1f} % of its 187.5 us wire time at 400 kHz")
    print(f"  main-loop iteration (recording motor, no physics): {mp['main_loop_us']:.1f} us")
    print(f"  protocol v2 pass (swap, judge, pack): {mp['v2_poll_us_frame']:.1f} us with a frame, "
          f"{mp['v2_poll_us_idle']:.1f} us without")
    print(f"firmware.v2_poll_us.frame {mp['v2_poll_us_frame']:.1f}")
    print(f"firmware.v2_poll_us.idle {mp['v2_poll_us_idle']:.1f}")
    print(f"  simulated joint turning at 60 rpm: {mp['sim_virtual_s_per_wall_s']:.1f} virtual s per wall s")
    print("host simulator, CPython")
    import simspeed
    speed = simspeed.virtual_per_wall(lambda: time.perf_counter_ns() // 1000)
    print(f"  simulated joint turning at 60 rpm: {speed:.1f} virtual s per wall s")

    import host
    cycles = {protocol: host.control_cycle(protocol=protocol) for protocol in ("legacy", "v2")}
    for protocol, c in cycles.items():
        what = "2 reads + 1 position write per joint" if protocol == "legacy" else "1 combined transaction per joint"
        print(f"host, 4-joint control cycle over {protocol} ({what}) on the simulated bus")
        print(f"  wire: {c['bits']:.0f} bit times = {c['wire_us']:.0f} us at 400 kHz")
        print(f"  bus: {c['bus_us']:.0f} us per cycle with the joint chip's clock stretching (sim/chip_costs.json)")
        print(f"  host CPU: {c['host_us']:.0f} us per cycle = {c['fraction']:.2f} x the wire time "
              f"(the simulator itself: {c['sim_us']:.0f} us, excluded)")
    for protocol, c in cycles.items():
        print(f"{protocol}.cycle_bits.4joints {c['bits']:.0f}")
        for khz in (400, 1000):
            print(f"{protocol}.cycle_rate_hz.4joints.{khz}khz {khz * 1000 / c['bits']:.0f}")
    import v2_attack
    attacks = (("joint", v2_attack.attack_joint(100_000, seed=1), "applied"),
               ("host", v2_attack.attack_host(100_000, seed=2), "accepted_wrong"))
    print("protocol v2 under attack: 100,000 corrupted frames each way (seeded; tests/v2_attack.py)")
    for side, r, bad in attacks:
        kinds = ", ".join(f"{k} {n}" for k, n in r.by_kind.items())
        print(f"  to the {side}: {kinds}; unchanged by the corruption {r.identical}")
        print(f"v2.attack.{side}.frames {r.frames}")
        print(f"v2.attack.{side}.{bad} {getattr(r, bad)}")
        print(f"v2.attack.{side}.uncounted {r.uncounted}")
        print(f"v2.attack.{side}.intact_lost {r.intact_lost}")
    b = host.bridge_throughput()
    print("HIL bridge framing over the simulator's pseudo-terminal (real time)")
    print(f"  {b['per_s']:.0f} PING transactions/s ({b['us']:.0f} us each, serial round trip included)")
    print("communicator, 4 joints in position mode, simulated bus")
    for rate in (100.0, 250.0, 500.0):
        v = host.communicator_virtual(rate)
        print(f"  {rate:>5.0f} Hz, virtual time: achieved {v['rate']:6.1f} Hz, jitter {v['jitter_us']:5.0f} us, "
              f"{v['overruns']:4d}/{v['cycles']} overruns, host CPU {v['host_share'] * 100:5.1f} % of bus time")
    for rate in (100.0, 250.0, 500.0):
        r = host.communicator_realtime(rate)
        print(f"  {rate:>5.0f} Hz, real time ({r['scheduling']}): achieved {r['rate']:6.1f} Hz, "
              f"jitter {r['jitter_us']:5.0f} us, {r['overruns']:4d}/{r['cycles']} overruns, "
              f"host CPU {r['host_share'] * 100:5.1f} % (+ simulator {r['sim_share'] * 100:.0f} %)")
    print("panel, `bioscara panel` in a pseudo-terminal on the simulated arm")
    panel = subprocess.run([sys.executable, str(ROOT / "bench" / "panel.py")], capture_output=True, text=True,
                           check=True).stdout
    print("".join(f"  {line}\n" for line in panel.splitlines()), end="")
    print("the shared simulated arm (`sim:`), 4 joints in real time, % of one core")
    service = subprocess.run([sys.executable, str(ROOT / "bench" / "sim_service.py")], capture_output=True,
                             text=True, check=True).stdout
    print("".join(f"  {line}\n" for line in service.splitlines()), end="")


if __name__ == "__main__":
    main()
