"""The host's protocol v2 link (the spec: firmware/joint/spec/protocol_v2.py): one combined transaction per
exchange, writing a mailbox frame and reading the state block, with the checks that keep corrupted
or replayed data out.

A state block is taken only if its CRC (which covers the joint's address) matches, its marker bits
are right, and its `ack` is exactly the frame sent in the transaction before (the one the joint
judged in between) and differs from the last state taken: a replayed or stale block never gets in. Every frame gets the next sequence number, except a
command's retransmissions while the host waits for its verdict, which repeat it byte for byte (the
joint applies it once). Everything that went wrong is counted in `V2LinkStats`.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..bus.base import Bus
from ..errors import CommError, IncorrectStateError
from ..firmware.spec import protocol as P
from ..firmware.spec import protocol_v2 as V
from .base import Command, Link, LinkRejected, LinkState

SYNC_ATTEMPTS = 50  # exchanges before a joint that was asked to switch counts as not speaking v2
VERDICT_ATTEMPTS = 20  # exchanges waiting for a command's verdict
RETRY_PERIOD_S = 0.001  # the joint's main loop judges a frame within one pass (1 ms)
LOST_AFTER = 3  # corrupted states in a row before the joint may have left v2 (reboot, silence)
STATE_REGISTERS = (P.PING, P.ANGLEMOVED, P.GETENCODERRPM)  # what the state block carries


@dataclass(frozen=True)
class V2State:
    """A state block, in the spec's units: motor degrees and motor rpm."""

    flags: int
    verdict: int
    position_deg: float
    velocity_rpm: float
    ack: int


@dataclass
class V2LinkStats:
    """The host's view of a v2 link: what it sent and every kind of trouble it saw."""

    exchanges: int = 0
    bad_states: int = 0  # CRC or marker mismatch: a corrupted state block, discarded
    stale_states: int = 0  # ack not the frame sent before (replayed, or that frame not yet judged)
    unacknowledged: int = 0  # commands whose verdict never came
    link_rejects: int = 0  # stale states whose verdict is CRC / SEQUENCE / FRAME: a frame was damaged
    rejected: int = 0  # commands refused by the joint's checks (value, busy, ...)
    retransmissions: int = 0


V2Rejected = LinkRejected  # a refusal carries the joint's verdict as its `reason`


class V2Link(Link):
    name = "v2"

    def __init__(self, bus: Bus, address: int, joint: str = "") -> None:
        super().__init__(bus, address, joint or f"0x{address:02x}")
        self.bus: Bus = bus
        self.stats = V2LinkStats()
        self.seq = 0
        self.last: V2State | None = None
        self._acked = -1  # ack of the last state taken
        self._sent = -1  # seq of the frame sent in the latest transaction
        self._pending: tuple[int, bytes] | None = None  # (seq, frame) of a command awaiting its verdict
        self.bad_in_a_row = 0  # corrupted state blocks since the last intact one

    # ---- frames and states ----

    def _transfer(self, frame: bytes) -> V2State | None:
        expected = self._sent
        reply = self.bus.transfer(self.address, frame, V.STATE_SIZE)
        self._sent = frame[V.M_SEQ]
        self.stats.exchanges += 1
        return self.take(reply, expected)

    def take(self, reply: bytes, expected: int) -> V2State | None:
        """The state in `reply` if it is intact and acknowledges frame `expected` (not yet seen
        acknowledged); None (counted) otherwise."""
        decoded = V.decode_state(self.address, reply)
        if decoded is None:
            self.stats.bad_states += 1
            self.bad_in_a_row += 1
            return None
        self.bad_in_a_row = 0
        flags, verdict, position, velocity, ack = decoded
        if ack != expected or ack == self._acked:
            self.stats.stale_states += 1  # replayed, or the joint has not judged that frame yet
            if verdict in V.LINK_REASONS:
                self.stats.link_rejects += 1  # ... because it failed the joint's link checks
            return None
        self._acked = ack
        self.last = V2State(flags, verdict, position / (1 << V.POSITION_Q),
                            velocity / (1 << V.VELOCITY_Q), ack)
        return self.last

    def _frame(self, cmd: int, payload: bytes) -> bytes:
        self.seq = (self.seq + 1) & V.SEQ_MASK
        return V.encode_frame(self.address, cmd, payload, self.seq)

    # ---- exchanges ----

    def sync(self, attempts: int = SYNC_ATTEMPTS) -> V2State:
        """Learn where the joint's sequence stands (after a switch, or taking over from another
        host): NONE frames, each new relative to the ack last seen, until the joint acknowledges
        one of them. Returns that state; the next frame continues the sequence."""
        previous = None
        for _ in range(attempts):
            frame = self._frame(V.CMD_NONE, b"")
            try:
                reply = self.bus.transfer(self.address, frame, V.STATE_SIZE)
            except CommError:
                reply = b""
            self._sent = frame[V.M_SEQ]
            decoded = V.decode_state(self.address, reply) if reply else None
            if decoded is None:
                previous = None
                self.bus.sleep(RETRY_PERIOD_S)
                continue
            ack = decoded[4]
            if ack == previous:
                self._acked = ack
                self.last = V2State(decoded[0], decoded[1], decoded[2] / (1 << V.POSITION_Q),
                                    decoded[3] / (1 << V.VELOCITY_Q), ack)
                return self.last
            if not 1 <= (self.seq - ack) & V.SEQ_MASK < V.SEQ_WINDOW:
                self.seq = ack  # the frame just sent is old to the joint: continue from its ack
                previous = None
            else:
                previous = self.seq
            self.bus.sleep(RETRY_PERIOD_S)
        raise CommError(f"joint {self.joint} does not answer in protocol v2")

    def exchange(self, cmd: int = V.CMD_NONE, payload: bytes = b"") -> V2State | None:
        """One cycle: send a frame (a setpoint or NONE, not waited for) and take the state.

        Raises V2Rejected if this state shows the joint refused the previous cycle's command."""
        previous = self.seq
        state = self._transfer(self._frame(cmd, payload))
        if state is not None:
            self._check_previous(state, previous)
        return state

    def _check_previous(self, state: V2State, previous: int) -> None:
        pending = self._pending
        self._pending = None
        if state.verdict != V.REASON_OK and pending is not None and pending[0] == previous:
            self.stats.rejected += 1
            raise V2Rejected(f"the joint rejected the command: {V.reason_string(state.verdict)}",
                             state.verdict, self.joint, state.flags)

    def send(self, cmd: int, payload: bytes) -> V2State | None:
        """A setpoint for this cycle: its verdict is checked by the next exchange."""
        state = self.exchange(cmd, payload)
        self._pending = (self.seq, b"")
        return state

    def await_verdict(self, cmd: int, payload: bytes) -> V2State:
        """Send a command and wait for its verdict (retransmitting it unchanged); the state that
        carries the verdict. Raises LinkRejected or CommError."""
        frame = self._frame(cmd, payload)
        seq = self.seq
        for attempt in range(VERDICT_ATTEMPTS):
            if attempt:
                self.stats.retransmissions += 1
                self.bus.sleep(RETRY_PERIOD_S)
            state = self._transfer(frame)
            if state is None or state.ack != seq:
                continue
            if state.verdict != V.REASON_OK:
                self.stats.rejected += 1
                raise V2Rejected(f"the joint rejected {_name(cmd)}: {V.reason_string(state.verdict)}",
                                 state.verdict, self.joint, state.flags)
            return state
        self.stats.unacknowledged += 1
        raise CommError(f"joint {self.joint} did not acknowledge {_name(cmd)} "
                        f"within {VERDICT_ATTEMPTS} exchanges")

    def poll(self) -> V2State:
        """A fresh state (NONE frames until one arrives)."""
        for attempt in range(VERDICT_ATTEMPTS):
            if attempt:
                self.bus.sleep(RETRY_PERIOD_S)
            state = self.exchange()
            if state is not None:
                return state
        raise CommError(f"joint {self.joint} sent no intact, fresh state in {VERDICT_ATTEMPTS} exchanges")

    # ---- the link interface ----

    def read(self, reg: P.Register) -> tuple[tuple, int]:
        """The registers the state block carries; any other exists in the legacy map only."""
        if reg.addr not in STATE_REGISTERS:
            raise IncorrectStateError(f"{reg.name} is not in the v2 state block (the legacy map has it)",
                                      joint=self.joint)
        state = self.poll()
        if reg.addr == P.PING:
            return (P.ACK,), state.flags
        return ((state.position_deg,) if reg.addr == P.ANGLEMOVED else (state.velocity_rpm,)), state.flags

    def command(self, command: Command) -> int:
        return self.await_verdict(command.register, command.payload).flags

    def cycle(self, setpoint: Command | None) -> LinkState | None:
        """One exchange carrying `setpoint`, whose verdict the next cycle checks."""
        state = self.exchange() if setpoint is None else self.send(setpoint.register, setpoint.payload)
        return None if state is None else LinkState(state.flags, state.position_deg, state.velocity_rpm)

    @property
    def lost(self) -> bool:
        return self.bad_in_a_row >= LOST_AFTER


def _name(cmd: int) -> str:
    reg = P.BY_ADDR[cmd]
    return reg.name if reg is not None else f"command 0x{cmd:02x}"
