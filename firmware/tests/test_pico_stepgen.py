"""PIO step generation: burst words and timing, the PIO program on a PIO model, acknowledged pulses.

Plain functions and bare asserts: this module runs under CPython (pytest) and the MicroPython unix
port (mprun.py); the fakes are pico_fakes.py's.
"""

import sys

from joint.pico import stepgen as sg
from joint.pico.stepgen import StepGenerator
from pico_fakes import FakeSM, raises


def test_usteps_per_pulse_and_period_math():
    assert [sg.usteps_per_pulse(m) for m in (256, 16, 1)] == [1, 16, 256]
    raises(ValueError, sg.usteps_per_pulse, 3)
    assert sg.period_cycles(900, 900) == 12  # 1 MHz: 12.5 MHz / 1 MHz
    assert sg.period_cycles(-900, 900) == 12  # direction does not matter
    assert sg.period_cycles(625, 10000) == 200  # 62 500 pulses/s (1e6 usteps/s at 16 microsteps)
    assert sg.period_cycles(9000, 900) == sg.MIN_PERIOD == 6
    assert sg.period_cycles(1, 10000) == sg.MAX_PERIOD == 0x3FFF + 5  # 100 pulses/s
    assert sg.period_cycles(0, 900) == sg.MAX_PERIOD


def test_burst_words():
    w = sg.burst_word(100, 125)
    assert w & 1 == 1 and (w >> 1) & 0x7FFF == 99 and w >> 16 == 120
    assert sg.burst_pulses(w) == 100 and sg.burst_cycles(w) == 5 + 100 * 125
    w = sg.burst_word(-1, 3)  # clamped up to the shortest legal period
    assert w & 1 == 0 and sg.burst_pulses(w) == -1 and w >> 16 == sg.MIN_DELAY
    w = sg.burst_word(sg.MAX_PULSES, 10 ** 6)
    assert sg.burst_pulses(w) == sg.MAX_PULSES and w >> 16 == sg.MAX_DELAY
    assert w < (1 << 30)  # stays a small int on 32-bit MicroPython


def test_plan_burst_truncates_and_clamps():
    pulses, word = sg.plan_burst(10, 1, 900, 1000)
    assert pulses == 10 and sg.burst_cycles(word) <= 0.0009 * sg.SM_FREQ + 5
    assert sg.plan_burst(-10, 1, 900, 1000)[0] == -10
    assert sg.plan_burst(47, 16, 900, 1000)[0] == 2  # whole 16-ustep pulses only, toward zero
    assert sg.plan_burst(-47, 16, 900, 1000)[0] == -2
    assert sg.plan_burst(0, 1, 900, 1000) == (0, 0)
    assert sg.plan_burst(5000, 1, 900, 1875)[0] == 1875
    assert sg.plan_burst(-5000, 1, 900, 1875)[0] == -1875
    assert sg.plan_burst(50, 1, 0, 0) == (0, 0)


class _Instr:
    def __init__(self, program, op, args):
        self.op = op
        self.args = args
        self.side_value = None  # optional side-set: the pin keeps its level
        self.delay = 0
        program.append(self)

    def side(self, value):
        self.side_value = value
        return self

    def __getitem__(self, delay):
        self.delay = delay
        return self


class FakeRP2:
    """Just enough of rp2.asm_pio to record the program for the emulator below."""

    class PIO:
        OUT_LOW = 0
        SHIFT_RIGHT = 1

    def __init__(self):
        self.options = None

    def asm_pio(self, **options):
        self.options = options

        def assemble(f):
            program = []
            labels = {}

            def instr(op):
                return lambda *args: _Instr(program, op, args)

            def label(name):
                labels[name] = len(program)

            names = {"label": label}
            for op in ("pull", "push", "mov", "out", "jmp"):
                names[op] = instr(op)
            for token in ("block", "noblock", "pins", "x", "y", "isr", "osr", "x_dec", "y_dec"):
                names[token] = token
            g = f.__globals__
            saved = {}
            for key in names:
                if key in g:
                    saved[key] = g[key]
                g[key] = names[key]
            try:
                f()
            finally:
                for key in names:
                    if key in saved:
                        g[key] = saved[key]
                    else:
                        del g[key]
            return program, labels

        return assemble


def run_pio(program, labels, words, max_cycles=10 ** 6):
    """Cycle-level emulation of the burst program until it stalls on an empty TX FIFO."""
    reg = {"x": 0, "y": 0, "isr": 0, "osr": 0}
    tx = list(words)
    rx = []
    step = direction = 0
    rises, falls = [], []
    pc = cycle = 0
    while cycle < max_cycles:
        ins = program[pc]
        if ins.op == "pull" and not tx:
            break
        assert not (ins.op == "push" and len(rx) >= 4)
        if ins.side_value is not None and ins.side_value != step:
            (rises if ins.side_value else falls).append((cycle, direction))
            step = ins.side_value
        nxt = pc + 1
        if ins.op == "pull":
            reg["osr"] = tx.pop(0)
        elif ins.op == "mov":
            reg[ins.args[0]] = reg[ins.args[1]]
        elif ins.op == "out":
            dest, bits = ins.args
            value = reg["osr"] & ((1 << bits) - 1)
            reg["osr"] >>= bits
            if dest == "pins":
                direction = value
            else:
                reg[dest] = value
        elif ins.op == "jmp":
            cond, target = ins.args
            counter = cond[0]
            if reg[counter]:
                nxt = labels[target]
            reg[counter] = (reg[counter] - 1) & 0xFFFFFFFF
        elif ins.op == "push":
            rx.append(reg["isr"])
            reg["isr"] = 0
        cycle += 1 + ins.delay
        pc = nxt % len(program)
    return rises, falls, rx, cycle


def test_pio_program_emits_the_burst_it_is_given():
    fake = FakeRP2()
    sys.modules["rp2"] = fake
    try:
        program, labels = sg.burst_program()
    finally:
        del sys.modules["rp2"]
    assert fake.options["out_shiftdir"] == FakeRP2.PIO.SHIFT_RIGHT
    assert len(program) <= 32
    words = [sg.burst_word(3, 100), sg.burst_word(-2, sg.MIN_PERIOD), sg.burst_word(1, 50)]
    rises, falls, rx, cycles = run_pio(program, labels, words)
    assert len(rises) == len(falls) == 6  # STEP ends low
    assert [d for _, d in rises] == [1, 1, 1, 0, 0, 1]
    assert rx == words  # each burst acknowledged with its own word, in order
    assert cycles == sum(sg.burst_cycles(w) for w in words)
    starts = [c for c, _ in rises]
    assert starts[1] - starts[0] == 100 and starts[2] - starts[1] == 100
    assert starts[4] - starts[3] == sg.MIN_PERIOD
    for (rise, _), (fall, _) in zip(rises, falls):
        assert fall - rise == sg.HIGH_CYCLES  # 240 ns at 12.5 MHz
    for i in range(1, len(rises)):
        assert rises[i][0] - falls[i - 1][0] >= 3  # low time >= 240 ns even at the fastest rate
    assert starts[3] - falls[2][0] >= 3  # DIR is set while STEP is low, before the next edge


def test_step_generator_counts_only_acknowledged_pulses():
    sm = FakeSM()
    gen = StepGenerator(sm, 256)
    assert gen.issue(100, 1000) == 100
    assert gen.position == 0 and gen.commanded == 100 and not gen.idle()
    gen.poll()
    assert gen.position == 0  # still in the PIO
    sm.finish()
    gen.poll()
    assert gen.position == 100 and gen.idle() and gen.field == 100
    assert gen.issue(100, 1000) == 0  # nothing more is owed
    assert gen.issue(40, 1000) == -60
    gen.shift(-500)
    assert gen.commanded == -460 and gen.position == -400 and gen.field == 100  # never relabelled
    for _ in range(10):  # the PIO stalls: at most MAX_IN_FLIGHT bursts are queued
        gen.issue(gen.commanded + 10, 1000)
    assert len(sm.tx) == sg.MAX_IN_FLIGHT
    coarse = StepGenerator(FakeSM(), 16)
    assert coarse.issue(40, 1000) == 2 and coarse.commanded == 32


def test_step_generator_limits_the_rate():
    gen = StepGenerator(FakeSM(), 256, max_rate=100000)
    assert gen.issue(10 ** 6, 1000) == 90  # 90 % of 1 ms at 100 kHz
    assert abs(gen.max_usteps_per_s() - 90000) < 1e-6
    fast = StepGenerator(FakeSM(), 256, max_rate=10 ** 7)
    assert fast.issue(10 ** 6, 1000) == int(0.0009 * sg.SM_FREQ) // sg.MIN_PERIOD
