"""Simulated joints on one I2C bus in virtual time.

Every transaction advances the shared clock by its wire time at the bus speed (protocol.wire_bits)
plus the clock stretching the joint chip shows for it, and every joint's main loop runs at the
period the chip achieves, with its garbage-collection pauses (sim.chip: the cost table that
`make bench-chip` measures), so host waits, homing, stalls and the deadman all play out
deterministically, faster than real time and no faster than the chip.
"""

from ..spec.protocol import wire_bits
from .chip import ChipCosts

NACK_ERRNO = 121  # EREMOTEIO: what Linux I2C adapters report for an unacknowledged address

_DEFAULT = []  # the repository's cost table, loaded once


def default_costs():
    if not _DEFAULT:
        _DEFAULT.append(ChipCosts.load())
    return _DEFAULT[0]


class SimJointBus:
    """`chip`: a sim.chip.ChipCosts (default: the repository's table); sim.chip.FREE for a free
    chip (1 ms loop, no clock stretching)."""

    def __init__(self, clock, joints=(), bus_hz=400000, chip=None):
        self.clock = clock
        self.bus_hz = bus_hz
        self.chip = default_costs() if chip is None else chip
        self.joints = []
        self._by_addr = {}
        self._next = []  # per joint: time of its next main-loop iteration (us, float)
        self._iterations = []
        self._fraction_us = 0.0
        self._jitter = 0x2545F491  # LCG state of the loop-period jitter (chip.loop_jitter_us)
        self.bits = 0
        self.stretch_us = 0.0
        self.transactions = 0
        for joint in joints:
            self.add(joint)

    def add(self, joint):
        if joint.cfg.address in self._by_addr:
            raise ValueError("two joints at address 0x%02x" % joint.cfg.address)
        self.joints.append(joint)
        self._by_addr[joint.cfg.address] = joint
        self._next.append(float(self.clock.ticks_us()))
        self._iterations.append(0)

    def joint_at(self, addr):
        return self._by_addr.get(addr)

    @property
    def loop_us(self):
        """Main-loop period of every joint, us (without the garbage-collection pauses)."""
        return self.chip.loop_us

    def run_until(self, t_us):
        """Run every joint's main loop up to virtual time t_us."""
        clock = self.clock
        nxt = self._next
        period = self.chip.loop_us
        gc_every = self.chip.gc_every
        gc_pause = self.chip.gc_pause_us
        jitter = self.chip.loop_jitter_us
        count = len(nxt)
        while count:
            i = 0
            for k in range(1, count):
                if nxt[k] < nxt[i]:
                    i = k
            t = nxt[i]
            if t > t_us:
                break
            now = int(t)
            if now > clock.now_us:
                clock.now_us = now
            self.joints[i].tick()
            n = self._iterations[i] + 1
            self._iterations[i] = n
            late = gc_pause if gc_every and n % gc_every == 0 else 0.0
            if jitter:
                self._jitter = (self._jitter * 1103515245 + 12345) & 0x7FFFFFFF
                late += jitter * (self._jitter >> 15) / 65536.0
            nxt[i] = t + period + late
        if t_us > clock.now_us:
            clock.now_us = t_us

    def sleep(self, seconds):
        self.run_until(self.clock.now_us + int(seconds * 1e6 + 0.5))

    def boot(self, limit_s=10.0):
        """Run until every joint has finished its boot sequence and joined the bus (True), or
        `limit_s` simulated seconds have passed (False)."""
        deadline = self.clock.now_us + int(limit_s * 1e6)
        while not all(joint.online for joint in self.joints):
            if self.clock.now_us >= deadline:
                return False
            self.sleep(0.01)
        return True

    def _spend(self, bits, stretch_us=0.0):
        self.bits += bits
        self.stretch_us += stretch_us
        self._fraction_us += bits * 1e6 / self.bus_hz + stretch_us
        whole = int(self._fraction_us)
        self._fraction_us -= whole
        self.run_until(self.clock.now_us + whole)

    def transfer(self, addr, data, read_len):
        """One transaction: write `data` (None for a plain read), then read `read_len` bytes.

        Raises OSError(NACK_ERRNO) when no joint acknowledges the address.
        """
        self.run_until(self.clock.now_us)
        self.transactions += 1
        joint = self._by_addr.get(addr)
        if joint is None or not joint.online:
            self._spend(wire_bits(0, 0))
            raise OSError(NACK_ERRNO, "no ACK from I2C address 0x%02x" % addr)
        reply = joint.target.transfer(data, read_len)
        if joint.target.serves_memory:
            stretch = self.chip.mem_held_us  # the v2 memory map is served in C
        else:
            stretch = self.chip.scl_held_us(data[0] if data else None, data is not None and len(data) > 1)
        if data is None:
            self._spend(2 + 9 * (1 + read_len), stretch)  # START, address + data, STOP: no write phase
        else:
            self._spend(wire_bits(len(data), read_len), stretch)
        return reply

    def scan(self):
        """Addresses that acknowledge, like i2cdetect's quick-write probe."""
        found = []
        for addr in range(0x08, 0x78):
            try:
                self.transfer(addr, b"", 0)
                found.append(addr)
            except OSError:
                pass
        return found
