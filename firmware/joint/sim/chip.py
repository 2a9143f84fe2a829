"""What the joint chip costs, for the simulated bus: clock stretching per transaction and the main
loop's period, from the cost table `make bench-chip` measures on the emulated Pico
(chip_costs.json next to this file; format in README, "The simulated arm").

    costs = ChipCosts.load()          # the repository's table
    costs.scl_held_us(reg, command)   # us the chip holds SCL for one transaction on register reg
    costs.mem_held_us                 # ... for one transaction on the v2 memory map (served in C)
    costs.loop_us                     # main-loop period, us
    costs.gc_every, costs.gc_pause_us # every gc_every-th iteration ends gc_pause_us late
    costs.loop_jitter_us              # each iteration ends up to this much late (uniform, seeded)
    costs.perturbed(scl_scale, loop_jitter_us)  # a variant: all clock stretching scaled, jitter
    FREE                              # no costs: 1 ms loop, no stretching (unit tests of logic)

MicroPython-compatible like the rest of joint.sim.
"""

import json

from ..spec import protocol

TABLE = "chip_costs.json"


class ChipCosts:
    def __init__(self, data):
        held = data.get("scl_held_us", {})
        default = data.get("scl_held_us_default", {})
        self.source = data.get("source", "")
        self._read = float(default.get("read", 0.0))
        self._command = float(default.get("command", 0.0))
        self.mem_held_us = float(data.get("scl_held_us_mem", 0.0))
        self._held = {}
        for name in held:
            self._held[protocol.register(name).addr] = float(held[name])
        hz = float(data.get("loop_hz", 1000.0))
        if not hz > 0.0:
            raise ValueError("%s: loop_hz must be positive" % TABLE)
        self.loop_us = 1e6 / hz
        self.gc_every = int(data.get("gc_every", 0))
        self.gc_pause_us = float(data.get("gc_pause_us", 0.0))
        self.loop_jitter_us = float(data.get("loop_jitter_us", 0.0))

    @classmethod
    def load(cls, path=None):
        if path is None:
            path = __file__.rsplit("/", 1)[0] + "/" + TABLE if "/" in __file__ else TABLE
        with open(path) as f:
            return cls(json.load(f))

    def perturbed(self, scl_scale=1.0, loop_jitter_us=0.0):
        """A copy with every clock stretching time scaled by `scl_scale` and `loop_jitter_us` of
        loop-period jitter: the chip a little faster or slower than measured, for margins."""
        other = ChipCosts({})
        other.loop_us = self.loop_us
        other.gc_every = self.gc_every
        other.gc_pause_us = self.gc_pause_us
        other._read = self._read * scl_scale
        other._command = self._command * scl_scale
        other.mem_held_us = self.mem_held_us * scl_scale
        other._held = {reg: us * scl_scale for reg, us in self._held.items()}
        other.loop_jitter_us = float(loop_jitter_us)
        other.source = "%s, SCL x%g, loop jitter %g us" % (self.source, scl_scale, loop_jitter_us)
        return other

    def scl_held_us(self, reg, command):
        """Clock stretching of one transaction addressed to register `reg` (None: an address-only
        probe, which the IRQ path answers without a handler); `command`: it carried a payload."""
        if reg is None:
            return 0.0
        held = self._held.get(reg)
        if held is not None:
            return held
        return self._command if command else self._read


FREE = ChipCosts({"loop_hz": 1000.0})
