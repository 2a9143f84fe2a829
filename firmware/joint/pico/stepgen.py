"""Step/dir pulses from an RP2040/RP2350 PIO state machine, fed one burst per main-loop tick.

Scheme: the ramp generator (joint.motion.tickramp.TickRamp) runs in the main loop. Each update() turns the
ramp's advance since the last tick into one burst word "N pulses, direction d, period P" and puts
it into the state machine's TX FIFO. The PIO program sets DIR, emits the N pulses at P cycles
each and pushes the word back into the RX FIFO as an acknowledgement. The driver position is the
sum of acknowledged bursts: it counts only pulses that have left the pin. The position in flight
(queued but not acknowledged) is exact too, so a closed-loop relabel can shift both.

Bursts are sized to fill BURST_FILL (90 %) of the tick that just elapsed, so with a steady loop
each one ends just before the next arrives and the pulse train is even within a tick. If the loop
stalls, the FIFO runs dry and the motor pauses; the next burst then carries the missed distance at
a higher rate (bounded by `max_rate`). The average speed over a tick is exact; the pulse spacing
inside it is quantised to one PIO cycle.

Burst word (30 bits, a small int on 32-bit ports), shifted out LSB first:
    bit 0        DIR level (1: the driver position increases)
    bits 1..15   pulses - 1                       (1..32768 pulses)
    bits 16..29  low-phase delay Y                (period P = Y + PERIOD_OVERHEAD cycles)

Timing at SM_FREQ = 12.5 MHz (an integer divider of 125 MHz on RP2040 and 150 MHz on RP2350):
STEP high 3 cycles (240 ns), low >= 3 cycles, so the shortest period is 6 cycles (480 ns,
2.08 MHz) and the longest 16388 cycles (1.31 ms). The TMC2209 needs about 100 ns high and low
and 20 ns DIR set-up; DIR changes 160 ns before the first rising edge of a burst.

Limits: the pulse rate inside a burst is at most 2.08 MHz (the PIO) and `max_rate` (config
max_step_rate); the average speed is BURST_FILL of that. With MRES = 256 one pulse is one library
ustep, so 1.2 MHz gives 1.08 M usteps/s = 1266 rpm (the joints' fastest setting is ~1146 rpm).
Speed changes take effect at the next tick: one loop period of latency.
"""

from array import array

from ..micro import const, micropython, ptr32
from ..motion.fixed import state_word

SM_FREQ = const(12500000)
HIGH_CYCLES = const(3)  # STEP high time: the pulse instruction plus its 2-cycle delay
PERIOD_OVERHEAD = const(5)  # cycles per pulse beyond Y: high (3), last low-loop pass, pulse-loop jump
MIN_DELAY = const(1)  # Y >= 1 keeps STEP low >= 3 cycles
MAX_DELAY = const(0x3FFF)
MAX_PULSES = const(0x8000)
MIN_PERIOD = const(6)  # MIN_DELAY + PERIOD_OVERHEAD
MAX_PERIOD = const(0x3FFF + 5)  # MAX_DELAY + PERIOD_OVERHEAD
BURST_FILL = 0.9  # issue() uses 9 // 10 on the integer path
MAX_IN_FLIGHT = const(4)  # bursts queued or unacknowledged; 4 keeps put() and the PIO push non-blocking


def usteps_per_pulse(microsteps):
    """Library usteps (1/256 full step) moved by one STEP pulse at `microsteps` per full step."""
    if microsteps < 1 or microsteps > 256 or 256 % microsteps:
        raise ValueError("microsteps must be a power of two in 1..256, got %r" % (microsteps,))
    return 256 // microsteps


def period_cycles(pulses, window_us, sm_freq=SM_FREQ):
    """PIO cycles per pulse for |pulses| pulses spread over `window_us` microseconds, clamped to
    MIN_PERIOD..MAX_PERIOD (slower speeds simply finish their burst early). Integers only:
    sm_freq must be a whole number of kHz * 100 (12.5 MHz: 25 cycles per 2 us)."""
    n = pulses if pulses > 0 else -pulses
    per_2us = sm_freq // 500000
    if n * MAX_PERIOD * 2 <= per_2us * window_us:
        return MAX_PERIOD
    p = per_2us * window_us // (2 * n)
    return MIN_PERIOD if p < MIN_PERIOD else p


def burst_word(pulses, period):
    """Word for |pulses| (1..MAX_PULSES) pulses, the sign giving the direction, at `period` cycles."""
    n = pulses if pulses > 0 else -pulses
    delay = period - PERIOD_OVERHEAD
    delay = MIN_DELAY if delay < MIN_DELAY else MAX_DELAY if delay > MAX_DELAY else delay
    return (delay << 16) | ((n - 1) << 1) | (1 if pulses > 0 else 0)


def burst_pulses(word):
    """Signed pulse count of a burst word (the PIO echoes words back as acknowledgements)."""
    n = ((word >> 1) & 0x7FFF) + 1
    return n if word & 1 else -n


def burst_cycles(word):
    """PIO cycles the burst takes: 4 to set up, N periods, 1 to acknowledge."""
    n = ((word >> 1) & 0x7FFF) + 1
    return 5 + n * (((word >> 16) & MAX_DELAY) + PERIOD_OVERHEAD)


def plan_burst(owed_usteps, upp, window_us, max_pulses, sm_freq=SM_FREQ):
    """(pulses, word): whole pulses of `upp` usteps toward `owed_usteps` (int, truncated toward
    zero, at most max_pulses), spread over `window_us` microseconds. (0, 0) when there is nothing
    to send."""
    pulses = owed_usteps // upp if owed_usteps >= 0 else -(-owed_usteps // upp)
    if pulses > max_pulses:
        pulses = max_pulses
    elif pulses < -max_pulses:
        pulses = -max_pulses
    if pulses == 0:
        return 0, 0
    return pulses, burst_word(pulses, period_cycles(pulses, window_us, sm_freq))


def burst_program():
    """The PIO program (hardware only: imports rp2). Side-set drives STEP, OUT drives DIR."""
    import rp2

    high = HIGH_CYCLES - 1

    @rp2.asm_pio(out_init=rp2.PIO.OUT_LOW, sideset_init=rp2.PIO.OUT_LOW,
                 out_shiftdir=rp2.PIO.SHIFT_RIGHT)
    def burst():
        # asm_pio supplies these names. Only two instructions use .side(), which makes side-set
        # optional: the others leave STEP as it is, low outside the pulse.
        pull(block)
        mov(isr, osr)  # keep the word: it is the acknowledgement
        out(pins, 1)  # DIR
        out(x, 15)  # pulses - 1; the delay Y stays in the OSR
        label("pulse")
        mov(y, osr).side(1)[high]  # STEP high for HIGH_CYCLES
        label("low")
        jmp(y_dec, "low").side(0)
        jmp(x_dec, "pulse")
        push(block)

    return burst


class StepGenerator:
    """Feeds burst words to a state-machine-like object (put, get, rx_fifo) and tracks positions.

    position:  usteps of acknowledged bursts (the pulses that reached the driver);
    commanded: usteps handed to the PIO, position plus the bursts in flight.
    The counters live in the int32 array `s` ([position, commanded, in_flight, field, upp,
    cycles per 2 us, pulses per ms, state machine index in its PIO]) that the viper poll and issue
    work on. With `pio` (the address of the state machine's PIO block) they use its FIFO registers
    (FSTAT, TXFn, RXFn) instead of the StateMachine's methods: a method call from viper costs
    ~10 us on the chip, a register access a few cycles.
    """

    position = state_word(0)
    commanded = state_word(1)
    in_flight = state_word(2)
    field = state_word(3)  # usteps of acknowledged pulses, never relabelled, wrapping at 2**30

    def __init__(self, sm, microsteps=256, max_rate=1200000, sm_freq=SM_FREQ, pio=0, index=0):
        self._sm = sm
        self.pio = pio  # the PIO block's registers (an address on the chip), 0: sm's methods
        self.upp = usteps_per_pulse(microsteps)
        self._sm_freq = sm_freq
        self._max_rate = max_rate
        # max_step_rate >= 1000 (config): at least a pulse per ms
        self.s = array("i", (0, 0, 0, 0, self.upp, sm_freq // 500000, int(max_rate) // 1000, index & 3))

    def max_usteps_per_s(self):
        """Highest average speed: BURST_FILL of the time at the maximum pulse rate."""
        rate = self._sm_freq / MIN_PERIOD
        if self._max_rate < rate:
            rate = self._max_rate
        return BURST_FILL * rate * self.upp

    def poll(self):
        """Account for bursts the PIO has finished."""
        poll_steps(self.s, self._sm, self.pio)

    def issue(self, target, dt_us):
        """Queue one burst toward `target` (int usteps, the ramp position) spread over BURST_FILL
        of `dt_us` microseconds; returns the pulses queued (0 when there is nothing whole to send
        or the FIFO is busy). Integers only: it runs at 1 kHz on the board."""
        return issue_steps(self.s, self._sm, self.pio, target, dt_us)

    def shift(self, delta):
        """Relabel both positions by `delta` usteps (closed-loop re-sync, set home)."""
        s = self.s
        s[0] += delta
        s[1] += delta

    def idle(self):
        return self.s[2] == 0


# The viper functions read the state's words sign-extended, as joint.motion.tickramp.run_ramp explains.
# PIO registers as 32-bit word indices (RP2040 datasheet 3.7): FSTAT (RXEMPTY bits 8..11), TXF0..3,
# RXF0..3.
_FSTAT = const(1)
_TXF = const(4)
_RXF = const(8)
_RXEMPTY = const(8)


@micropython.viper
def poll_steps(s: ptr32, sm, pio: int):
    m = 1
    m <<= 31
    k = m + m - 1
    upp = ((s[4] + m) & k) - m
    wrap = 1
    wrap <<= 29
    wrap += wrap - 1  # the field counter's mask, 2**30 - 1: not a literal (no small int on 30-bit
    # ports), and no 2**30 on the way (a long int, allocated, where small ints are 31 bits)
    if pio:
        r = ptr32(pio)
        index = s[7] & 3
        empty = 1 << (_RXEMPTY + index)
        while not (r[_FSTAT] & empty):
            word = r[_RXF + index]
            n = ((word >> 1) & 0x7FFF) + 1  # burst_pulses(), inlined
            moved = (n if word & 1 else 0 - n) * upp
            s[0] = ((s[0] + m) & k) - m + moved
            s[3] = (((s[3] + m) & k) - m + moved) & wrap
            s[2] = ((s[2] + m) & k) - m - 1
        return
    while sm.rx_fifo():
        word = int(sm.get())
        n = ((word >> 1) & 0x7FFF) + 1
        moved = (n if word & 1 else 0 - n) * upp
        s[0] = ((s[0] + m) & k) - m + moved
        s[3] = (((s[3] + m) & k) - m + moved) & wrap
        s[2] = ((s[2] + m) & k) - m - 1


@micropython.viper
def issue_steps(s: ptr32, sm, pio: int, target: int, dt_us: int) -> int:
    m = 1
    m <<= 31
    k = m + m - 1
    if ((s[2] + m) & k) - m >= MAX_IN_FLIGHT:
        return 0
    window = dt_us * 9 // 10  # BURST_FILL
    per_2us = ((s[5] + m) & k) - m
    max_pulses = window * per_2us // (2 * MIN_PERIOD)
    limit = window * (((s[6] + m) & k) - m) // 1000
    if max_pulses > limit:
        max_pulses = limit
    if max_pulses > MAX_PULSES:
        max_pulses = MAX_PULSES
    commanded = ((s[1] + m) & k) - m
    owed = target - commanded
    upp = ((s[4] + m) & k) - m
    pulses = owed // upp if owed >= 0 else 0 - ((0 - owed) // upp)
    if pulses > max_pulses:
        pulses = max_pulses
    elif pulses < 0 - max_pulses:
        pulses = 0 - max_pulses
    if pulses != 0:
        # period_cycles() and burst_word(), inlined.
        n = pulses if pulses > 0 else 0 - pulses
        if n * MAX_PERIOD * 2 <= per_2us * window:
            delay = MAX_DELAY
        else:
            delay = per_2us * window // (2 * n) - PERIOD_OVERHEAD
            if delay < MIN_DELAY:
                delay = MIN_DELAY
        word = (delay << 16) | ((n - 1) << 1) | (1 if pulses > 0 else 0)
        if pio:
            r = ptr32(pio)
            r[_TXF + (s[7] & 3)] = word  # never full: at most MAX_IN_FLIGHT words in flight
        else:
            sm.put(word)
        s[1] = commanded + pulses * upp
        s[2] = ((s[2] + m) & k) - m + 1
    return pulses


def pio_registers(sm_id):
    """(address of the PIO block, index in it) of rp2.StateMachine(sm_id): 0..3 PIO0, 4..7 PIO1."""
    return 0x50200000 + (sm_id >> 2) * 0x100000, sm_id & 3
