"""Simulated-joint speed: virtual seconds per wall second for one joint turning at 60 rpm.

MicroPython-compatible, so bench/run.py measures it under both interpreters with the same code.
"""

from joint.spec import protocol as P
from joint.sim.clock import VirtualClock
from joint.sim.joint import make_joint
from joint.sim.stepper import SimStepper


def virtual_per_wall(wall_us, seconds=5.0):
    """`wall_us()` reads a microsecond wall clock."""
    clock = VirtualClock()
    stepper = SimStepper(clock, seed=1)
    joint = make_joint("J1", clock, stepper, write=lambda line: None)
    while not joint.online:
        clock.advance(1000)
        joint.tick()
    joint.core.flags &= ~P.FLAG_NOTENABLED
    stepper.set_current(20)
    stepper.set_rpm(60)
    t0 = wall_us()
    for _ in range(int(seconds * 1000)):
        clock.advance(1000)
        joint.tick()
    return seconds * 1e6 / (wall_us() - t0)
