"""MicroPython benchmark of the firmware's IRQ path and main loop (run by bench/run.py).

The handler is driven directly with the event sequence of one transaction (no fake-bus overhead);
a do-nothing handler driven the same way is subtracted. Prints one `name value` line per figure.
"""

import time

from joint.config import schema as config
from joint.spec import protocol as P
from joint.core.controller import JointController
from joint.links.i2c_target import I2CTargetAdapter
from joint.core.irq import FTAB_Q_IN, FTAB_Q_OUT
from joint.console.log import Logger
from joint.sim.clock import VirtualClock
from harness import RecordingMotor
import simspeed

RQ, WQ, E_R, E_W = 4, 8, 16, 32


class Stub:
    """The minimum of machine.I2CTarget a handler needs, replaying preset events."""

    def __init__(self):
        self.event = 0
        self.rx = bytearray(8)
        self.rx_len = 0

    def irq(self, handler=None, trigger=None, hard=False):
        return self

    def flags(self):
        return self.event

    def readinto(self, buf):
        n = self.rx_len
        for i in range(n):
            buf[i] = self.rx[i]
        self.rx_len = 0  # the FIFO is drained
        return n

    def write(self, buf):
        return len(buf)


def sequence(stub, handler, frame, read_len, events):
    stub.rx_len = len(frame)
    for i in range(len(frame)):
        stub.rx[i] = frame[i]
    for event in events:
        stub.event = event
        handler(stub)


def bench_transaction(label, frame, read_len, n=2000):
    events = (WQ, E_W, RQ, RQ, E_R)  # the events the adapter asks for (i2c_target.TRIGGER)
    clock = VirtualClock()
    core = JointController(RecordingMotor(), clock, config.default("J1"), Logger("J1", write=lambda s: None))
    for _ in range(3000):
        clock.advance(1000)
        core.service()
    stub = Stub()
    adapter = I2CTargetAdapter(core)
    adapter.attach(stub)
    handler = adapter._irq

    def nothing(target):
        target.irq().flags()

    for fn in (handler, nothing):
        sequence(stub, fn, frame, read_len, events)
    t0 = time.ticks_us()
    for _ in range(n):
        sequence(stub, handler, frame, read_len, events)
        core._ftab[FTAB_Q_OUT] = core._ftab[FTAB_Q_IN]  # keep the queue from filling; the main loop is measured separately
    t1 = time.ticks_us()
    for _ in range(n):
        sequence(stub, nothing, frame, read_len, events)
    t2 = time.ticks_us()
    per = (time.ticks_diff(t1, t0) - time.ticks_diff(t2, t1)) / n
    wire = P.wire_bits(len(frame), read_len) / 400000 * 1e6
    print("irq_us_%s %.2f" % (label, per))
    print("irq_fraction_of_wire_%s %.4f" % (label, per / wire))


def bench_main_loop(n=5000):
    clock = VirtualClock()
    core = JointController(RecordingMotor(), clock, config.default("J1"), Logger("J1", write=lambda s: None))
    for _ in range(3000):
        clock.advance(1000)
        core.service()
    t0 = time.ticks_us()
    for _ in range(n):
        clock.advance(1000)
        core.service()
    print("main_loop_us %.2f" % (time.ticks_diff(time.ticks_us(), t0) / n))


def bench_sim_speed():
    print("sim_virtual_s_per_wall_s %.1f" % simspeed.virtual_per_wall(time.ticks_us))


def bench_v2_poll(n=1000):
    """Protocol v2's main-loop pass (MemLink: swap, judge, pack), with a SETRPM frame to judge
    and with nothing new; the fake target's transfer itself is not timed."""
    from v2rig import V2Rig
    rig = V2Rig()
    rig.to_v2()
    rig.command("SETUP", 50, 30, 0, 0)
    frames = [rig.frame("SETRPM", 10.0) for _ in range(n)]
    target = rig.switch.target
    service = rig.switch.service
    spent = 0
    import gc
    for frame in frames:
        target.transfer(frame, 8)
        gc.collect()  # the fake target allocates; the pass itself does not (test_v2): no GC in it
        t0 = time.ticks_us()
        service()
        spent += time.ticks_diff(time.ticks_us(), t0)
        rig.core._ftab[FTAB_Q_OUT] = rig.core._ftab[FTAB_Q_IN]  # the core's own pass is measured by main_loop_us
    print("v2_poll_us_frame %.2f" % (spent / n))
    gc.collect()
    t0 = time.ticks_us()
    for _ in range(n):
        service()
    print("v2_poll_us_idle %.2f" % (time.ticks_diff(time.ticks_us(), t0) / n))


bench_transaction("read_float", bytes([P.ANGLEMOVED]), 5)
bench_transaction("command_float", bytes([P.SETRPM, 0, 0, 0x20, 0x41]), 1)
bench_main_loop()
bench_v2_poll()
bench_sim_speed()
