"""Simulated joints on one I2C bus in virtual time.

Every transaction advances the shared clock by its wire time at the bus speed (protocol.wire_bits),
and every joint's main loop runs once per simulated millisecond in between, so host waits, homing,
stalls and the deadman all play out deterministically and faster than real time.
"""

from ..protocol import wire_bits

NACK_ERRNO = 121  # EREMOTEIO: what Linux I2C adapters report for an unacknowledged address
_TICK_US = 1000


class SimJointBus:
    def __init__(self, clock, joints=(), bus_hz=400000):
        self.clock = clock
        self.bus_hz = bus_hz
        self.joints = []
        self._by_addr = {}
        self._next_tick = clock.ticks_us()
        self._fraction_us = 0.0
        self.bits = 0
        self.transactions = 0
        for joint in joints:
            self.add(joint)

    def add(self, joint):
        if joint.cfg.address in self._by_addr:
            raise ValueError("two joints at address 0x%02x" % joint.cfg.address)
        self.joints.append(joint)
        self._by_addr[joint.cfg.address] = joint

    def joint_at(self, addr):
        return self._by_addr.get(addr)

    def run_until(self, t_us):
        """Run every joint's main loop up to virtual time t_us."""
        clock = self.clock
        while self._next_tick <= t_us:
            clock.now_us = self._next_tick
            for joint in self.joints:
                joint.tick()
            self._next_tick += _TICK_US
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

    def _spend(self, bits):
        self.bits += bits
        self._fraction_us += bits * 1e6 / self.bus_hz
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
        if data is None:
            self._spend(2 + 9 * (1 + read_len))  # START, address + data, STOP: no write phase
        else:
            self._spend(wire_bits(len(data), read_len))
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
