"""A joint read by a program that does not command it (a monitor, `info`, a plot beside a
commanding program): see commander.py for the rules that keep it from disturbing the commander."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, TypeVar

from ..bus.base import Bus
from ..commander import Commander, CommanderLeft, Holder
from ..errors import CommError, IncorrectStateError
from ..firmware.spec import protocol as P
from .base import Command, Link, LinkState
from .legacy import LegacyLink

FRESH_S = 0.005  # one fetch of the commander's state serves every joint read within this long
READ_WAIT_S = 1.0  # for a commander that has just opened a joint to read it
WATCH_ATTEMPTS = 3  # commanders that end one after another while a watcher asks each
T = TypeVar("T")


class WatchedLink(Link):
    """Reads in the legacy map while no other program commands the bus (under the watchers'
    shared lock), or while the commander has not opened this joint; else the commander's
    published copy of the registers it read: PING (flags), ANGLEMOVED, GETENCODERRPM, HOMEOFFSET
    and IDENTITY. Never commands."""

    name = "watched"

    def __init__(self, bus: Bus, address: int, joint: str, commander: Commander) -> None:
        super().__init__(bus, address, joint)
        self.legacy = LegacyLink(bus, address, joint)
        self.commander = commander
        self.holder: Holder | None = None  # the commander the last read went through, if any
        self._fetched: tuple[float, dict[str, Any]] | None = None

    def read(self, reg: P.Register) -> tuple[tuple, int]:
        return self._watched(lambda holder: self._read_through(holder, reg))

    def _watched(self, through: Callable[[Holder | None], T]) -> T:
        """`through(holder)` under one watch, and under a new one if the commander it named let
        go meanwhile (a command ending while we ask it): its leaving is no error of the joint."""
        attempt = 1
        while True:
            with self.commander.watch() as holder:
                self.holder = holder
                try:
                    return through(holder)
                except CommanderLeft:
                    if attempt == WATCH_ATTEMPTS:
                        raise
            attempt += 1
            self._fetched = None

    def _read_through(self, holder: Holder | None, reg: P.Register) -> tuple[tuple, int]:
        entry = None if holder is None else self.published(holder)
        if entry is None:
            return self.legacy.read(reg)
        assert holder is not None
        return self._published_read(holder, entry, reg)

    def published(self, holder: Holder) -> dict[str, Any] | None:
        """This joint's entry in the commander's published state; None if the commander has not
        opened this joint (it is read directly then: the commander does not talk to it)."""
        now = time.monotonic()
        if self._fetched is None or now - self._fetched[0] > FRESH_S:
            self._fetched = (now, self.commander.published(holder))
        for entry in self._fetched[1].get("joints", {}).values():
            if entry.get("address") == self.address:
                return dict(entry)
        return None

    def _published_read(self, holder: Holder, entry: dict[str, Any], reg: P.Register) -> tuple[tuple, int]:
        deadline = time.monotonic() + READ_WAIT_S
        while not entry.get("read"):  # the commander opened it a moment ago; its first read follows
            if time.monotonic() > deadline:
                raise CommError(f"{holder.describe()} has opened this joint but not read it", joint=self.joint)
            time.sleep(FRESH_S)
            entry = self.published(holder) or entry
        flags = int(entry["flags"])
        values: dict[int, Any] = {P.PING: (P.ACK,), P.ANGLEMOVED: (entry["position_deg"],),
                                  P.GETENCODERRPM: (entry["velocity_rpm"],), P.HOMEOFFSET: (entry["offset"],)}
        if entry.get("identity"):
            values[P.IDENTITY] = tuple(entry["identity"])
        if reg.addr not in values:
            raise IncorrectStateError(f"{reg.name} cannot be read while {holder.describe()} commands the arm",
                                      joint=self.joint)
        return values[reg.addr], flags

    def command(self, command: Command) -> int:
        raise IncorrectStateError(f"{command.name}: this program only watches the arm", joint=self.joint)

    def cycle(self, setpoint: Command | None) -> LinkState | None:
        """Position, velocity and flags from one source: the joint, or the commander's copy
        (None while a commander is starting and publishes nothing yet: the last state stands)."""
        if setpoint is not None:
            self.command(setpoint)
        return self._watched(self._state_through)

    def _state_through(self, holder: Holder | None) -> LinkState | None:
        if holder is not None and not holder.socket:
            return None
        entry = None if holder is None else self.published(holder)
        if entry is None:
            return self.legacy.cycle(None)
        if not entry.get("read"):
            return None  # the commander has opened the joint but not read its state yet
        return LinkState(int(entry["flags"]), float(entry["position_deg"]), float(entry["velocity_rpm"]))
