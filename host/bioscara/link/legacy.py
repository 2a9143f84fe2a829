"""The original register map: one transaction per register read or command (original-host-behaviour.md 2.4)."""

from __future__ import annotations

from ..bus.base import Bus
from ..errors import BioscaraError, CommError
from ..firmware.spec import protocol as P
from .base import Command, Link, LinkRejected, LinkState, legacy_reason

_ANGLE = P.register(P.ANGLEMOVED)
_RPM = P.register(P.GETENCODERRPM)


class LegacyLink(Link):
    name = "legacy"

    def __init__(self, bus: Bus, address: int, joint: str) -> None:
        super().__init__(bus, address, joint)
        self.bus: Bus = bus

    def transfer(self, write: bytes, read_len: int) -> bytes:
        """One bus transaction; a bus error names this joint as well as its address."""
        try:
            return self.bus.transfer(self.address, write, read_len)
        except CommError as exc:
            if exc.joint:
                raise
            raise CommError(exc.detail, joint=self.joint) from None

    def read(self, reg: P.Register) -> tuple[tuple, int]:
        reply = self.transfer(bytes([reg.addr]), reg.rsize + 1)
        flags = reply[-1]
        if flags & P.FLAG_ERROR:
            raise LinkRejected(f"the joint rejected the read of {reg.name}", 0, self.joint, flags)
        return reg.decode(reply[:-1]), flags

    def command(self, command: Command) -> int:
        (flags,) = self.transfer(bytes([command.register]) + command.payload, 1)
        if flags & P.FLAG_ERROR:
            raise self._rejected(command, flags)
        return flags

    def _rejected(self, command: Command, flags: int) -> LinkRejected:
        """Why the joint refused `command`: its LASTERROR."""
        try:
            (reason, register, _count), _ = self.read(P.register(P.LASTERROR))
        except BioscaraError:
            return LinkRejected(f"the joint rejected {command.name}", 0, self.joint, flags)
        reg = P.BY_ADDR[register]
        name = reg.name if reg else f"0x{register:02x}"
        return LinkRejected(f"the joint rejected {name}: {P.reject_string(reason)}", legacy_reason(reason),
                            self.joint, flags)

    def cycle(self, setpoint: Command | None) -> LinkState:
        """The setpoint's command, then two register reads (position, velocity)."""
        if setpoint is not None:
            self.command(setpoint)
        (position,), _ = self.read(_ANGLE)
        (velocity,), flags = self.read(_RPM)
        return LinkState(flags, position, velocity)
