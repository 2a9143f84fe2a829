"""How the host talks to one joint: one interface, `Link`, over three ways of reaching it.

* `legacy.LegacyLink`: the original register map, one transaction per register;
* `v2.V2Link`: protocol v2, one combined transaction per cycle (setpoint out, state block in);
* `watched.WatchedLink`: a program that only reads: the legacy map while no other program
  commands the bus, else the state that commander publishes (commander.py); it never sends a
  frame that could disturb the commander.

`Joint` (joint.py) holds one of them and never asks which. This package may import `bus.base`,
`errors`, `commander` and the shared protocol spec (`firmware.spec`).
"""

from .base import Command, Link, LinkRejected, LinkState
from .legacy import LegacyLink
from .v2 import V2Link, V2LinkStats
from .watched import WatchedLink

__all__ = ["Command", "LegacyLink", "Link", "LinkRejected", "LinkState", "V2Link", "V2LinkStats", "WatchedLink"]
