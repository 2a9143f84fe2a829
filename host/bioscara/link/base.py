"""The link interface every way of reaching a joint implements, and what travels over it."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

from ..errors import BioscaraError
from ..firmware.spec import protocol as P
from ..firmware.spec import protocol_v2 as V


@dataclass(frozen=True)
class Command:
    """A command register and its encoded payload, built once (with the joint's guards) and then
    sent by whichever link the joint speaks: a cycle's setpoint or a command awaiting its verdict."""

    register: int
    payload: bytes

    @property
    def name(self) -> str:
        reg = P.BY_ADDR[self.register]
        return reg.name if reg is not None else f"command 0x{self.register:02x}"


@dataclass(frozen=True)
class LinkState:
    """What one cycle returns, in the wire's units: status flags, motor degrees since home and
    encoder motor rpm."""

    flags: int
    position_deg: float
    velocity_rpm: float


class LinkRejected(BioscaraError):
    """The joint refused a command. `reason` is a protocol v2 verdict (REASON_*; a legacy
    reject reason is translated with the spec's FROM_LEGACY), `flags` the status flags that came
    with it."""

    def __init__(self, message: str, reason: int, joint: str | None = None, flags: int = 0) -> None:
        super().__init__(message, joint=joint)
        self.reason = reason
        self.flags = flags


def legacy_reason(reject: int) -> int:
    """The v2 verdict for a legacy reject reason (LASTERROR)."""
    return V.FROM_LEGACY[reject] if 0 <= reject < len(V.FROM_LEGACY) else V.REASON_COMMAND


class Link(ABC):
    """One joint reached one way. Every method is one exchange or a bounded series of them;
    failures raise CommError, refusals LinkRejected."""

    name = ""  # "legacy" or "v2": the protocol a user sees

    def __init__(self, bus: object, address: int, joint: str) -> None:
        self.bus = bus
        self.address = address
        self.joint = joint

    @abstractmethod
    def read(self, reg: P.Register) -> tuple[tuple, int]:
        """A readable register's decoded payload, and the status flags that came with it."""

    @abstractmethod
    def command(self, command: Command) -> int:
        """Send a command and wait for its verdict; the status flags after it."""

    @abstractmethod
    def cycle(self, setpoint: Command | None) -> LinkState | None:
        """One control cycle: `setpoint` (or none) out, the state in. None when no intact, fresh
        state arrived this time (the caller keeps the last one)."""

    @property
    def lost(self) -> bool:
        """True when the joint no longer seems to speak this link's protocol (it rebooted, or
        went back to the legacy map after a host silence)."""
        return False
