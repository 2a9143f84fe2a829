"""Protocol v2 under attack: randomly corrupted frames in each direction against the real firmware
(MemLink and the joint core on the fake mem-mode target) and the host's V2Link.

Corruptions, one per frame, chosen at random (seeded): 1-3 flipped bits, truncation (the write
stops early; a read ends early and the host reads 0xFF from the released bus), a byte inserted
before one of the frame's bytes, and a replay of one of the 63 frames before. Every corrupted frame is followed by the intact one, which must
get through (the link is not wedged by the attack). `make test` runs a few thousand of each,
`make bench` 100,000 of each.
"""

from __future__ import annotations

import random
from dataclasses import dataclass, field

from bioscara.bus.base import Bus
from bioscara.firmware.spec import protocol as P
from bioscara.firmware.spec import protocol_v2 as V
from bioscara.link.v2 import V2Link

from v2rig import V2Rig

KINDS = ("flip", "truncate", "insert", "replay")


@dataclass
class Result:
    frames: int = 0
    by_kind: dict[str, int] = field(default_factory=lambda: {kind: 0 for kind in KINDS})
    identical: int = 0  # a "corruption" that left the bytes as they were (nothing to catch)
    applied: int = 0  # corrupted commands the joint applied (must be 0)
    accepted_wrong: int = 0  # corrupted states whose values the host took (must be 0)
    uncounted: int = 0  # corruptions no link statistic counted (must be 0)
    intact_lost: int = 0  # intact frames after a corrupted one that did not get through (must be 0)
    counters: dict[str, int] = field(default_factory=dict)
    examples: list[str] = field(default_factory=list)  # the first few failures, for diagnosis

    def fail(self, what: str, kind: str, bad: bytes, intact: bytes) -> None:
        if len(self.examples) < 10:
            self.examples.append(f"{what} {kind}: {bad.hex()} (intact {intact.hex()})")


def corrupt(rng: random.Random, data: bytes, kind: str, history: list[bytes], pad: int) -> bytes:
    if kind == "flip":
        out = bytearray(data)
        for bit in rng.sample(range(len(data) * 8), rng.randint(1, 3)):
            out[bit // 8] ^= 1 << (bit % 8)
        return bytes(out)
    if kind == "truncate":
        keep = rng.randrange(1 if pad < 0 else 0, len(data))  # a write of 0 bytes has no frame
        return data[:keep] + (bytes([pad]) * (len(data) - keep) if pad >= 0 else b"")
    if kind == "insert":
        # Inside the frame: a byte appended after an intact mailbox leaves the intact command
        # (rightly applied; the state read that follows is misaligned and the host drops it).
        at = rng.randrange(len(data))
        out = data[:at] + bytes([rng.randrange(256)]) + data[at:]
        return out if pad < 0 else out[:len(data)]  # a read still clocks len(data) bytes
    return history[-rng.randint(1, min(len(history), V.SEQ_WINDOW - 1))]


def _command(rng: random.Random) -> tuple[str, tuple[int, ...], tuple[object, ...] | None]:
    """A random command, its values and the motor call it must cause (None: a NONE poll)."""
    choice = rng.randrange(4)
    if choice == 0:
        value = rng.randint(1, 100)
        return "SETCURRENT", (value,), ("set_current", value)
    if choice == 1:
        value = rng.randint(1, 100)
        return "SETHOLDCURRENT", (value,), ("set_hold_current", value)
    if choice == 2:
        value = rng.randint(-100000, 100000)
        return "MOVESTEPS", (value,), ("move_steps", value)
    return "", (), None


def _counted(link: object) -> int:
    return sum(getattr(link, name) for name in ("crc_errors", "sequence_errors", "frame_errors", "retries"))


def attack_joint(frames: int, seed: int = 1) -> Result:
    """Corrupted host->joint frames against the firmware: none may be applied."""
    rng = random.Random(seed)
    rig = V2Rig()
    rig.to_v2()
    rig.command("SETUP", 60, 30, 0, 0)
    motor = rig.motor
    result = Result()
    history: list[bytes] = []
    for _ in range(frames):
        name, values, call = _command(rng)
        intact = rig.frame(name, *values) if name else rig.frame()
        kind = KINDS[rng.randrange(len(KINDS))] if history else "flip"
        bad = corrupt(rng, intact, kind, history, -1)
        result.frames += 1
        result.by_kind[kind] += 1
        calls, counted = len(motor.calls), _counted(rig.link)
        rig.xfer(bad, V.STATE_SIZE)
        rig.tick()  # judged (and queued, were it accepted) ...
        rig.tick()  # ... and the queue applied to the motor
        if len(motor.calls) != calls:
            result.applied += 1
            result.fail("applied", kind, bad, intact)
        if _counted(rig.link) != counted + 1:
            result.uncounted += 1
            result.fail("uncounted", kind, bad, intact)
        calls = len(motor.calls)
        rig.xfer(intact, V.STATE_SIZE)
        rig.tick()
        rig.tick()
        if motor.calls[calls:] != ([call] if call else []):
            result.intact_lost += 1
            result.fail("intact lost", kind, bad, intact)
        history.append(intact)
    link = rig.link
    result.counters = {name: getattr(link, name) for name in
                       ("frames", "applied", "polls", "crc_errors", "sequence_errors", "frame_errors",
                        "retries", "rejected", "deferred")}
    return result


class RigBus(Bus):
    """A bus to one V2Rig joint whose replies pass through `tamper` (the attack's hook)."""

    scheme = "rig"

    def __init__(self, rig: V2Rig) -> None:
        super().__init__(attempts=1)
        self.rig = rig
        self.tamper = lambda reply: reply

    def _transfer_once(self, addr: int, write: bytes | None, read_len: int) -> bytes:
        reply = self.rig.xfer(write, read_len)
        self.rig.tick()  # the joint's main loop runs between transactions
        return self.tamper(reply)

    def _probe(self, addr: int) -> bool:
        return True

    def sleep(self, seconds: float) -> None:
        self.rig.run_ms(max(1, int(seconds * 1000)))

    def monotonic(self) -> float:
        return self.rig.clock.ticks_ms() / 1000


def attack_host(frames: int, seed: int = 2) -> Result:
    """Corrupted joint->host state blocks against V2Link: no wrong value may be taken."""
    rng = random.Random(seed)
    rig = V2Rig()
    rig.to_v2()
    bus = RigBus(rig)
    link = V2Link(bus, rig.address, "J1")
    link.sync()
    result = Result()
    history: list[bytes] = []
    motor = rig.motor
    for i in range(frames):
        motor.angle = rng.uniform(-20000.0, 20000.0)  # a new state every transaction
        motor.rpm = rng.uniform(-1500.0, 1500.0)
        rig.tick()
        kind = KINDS[rng.randrange(len(KINDS))] if history else "flip"
        seen: dict[str, bytes] = {}

        def tamper(reply: bytes) -> bytes:
            seen["true"] = reply
            bad = corrupt(rng, reply, kind, history, 0xFF)
            seen["bad"] = bad
            return bad
        bus.tamper = tamper
        before = link.stats.bad_states + link.stats.stale_states
        state = link.exchange()
        result.frames += 1
        result.by_kind[kind] += 1
        true, bad = seen["true"], seen["bad"]
        if bad == true:
            result.identical += 1
        elif link.stats.bad_states + link.stats.stale_states != before + 1:
            result.uncounted += 1
            result.fail("uncounted", kind, bad, true)
        if state is not None and bad != true:
            truth = V.decode_state(rig.address, true)
            got = (state.flags, state.verdict, round(state.position_deg * 64), round(state.velocity_rpm * 8),
                   state.ack)
            if truth is None or got != truth:
                result.accepted_wrong += 1
                result.fail("accepted", kind, bad, true)
        history.append(true)
        bus.tamper = lambda reply: reply
        if link.exchange() is None:
            result.intact_lost += 1
            result.fail("intact lost", kind, bad, true)
    result.counters = {"exchanges": link.stats.exchanges, "bad_states": link.stats.bad_states,
                       "stale_states": link.stats.stale_states}
    return result


def check_crc_catches_every_error_of_up_to_3_bits(address: int = 0x11) -> int:
    """Exhaustively: every 1-, 2- and 3-bit error in a mailbox and in a state block is caught.
    Returns the number of error patterns tried."""
    frame = V.encode_frame(address, P.MOVESTEPS, P.register("MOVESTEPS").encode(123456), 42)
    state = bytearray(V.STATE_SIZE)
    state[0] = V.STATUS_MARKER | 0x0C
    state[5] = V.VELOCITY_MARKER
    state[6] = 42
    state[7] = V.state_crc(state, 0, address)
    tried = 0
    for block, check in ((frame, lambda b: V.mailbox_crc(b, 0, address) == b[V.M_CRC]),
                         (bytes(state), lambda b: V.state_crc(b, 0, address) == b[-1])):
        assert check(block)
        bits = len(block) * 8
        for a in range(bits):
            for b in range(a, bits):
                for c in range(b, bits):
                    flips = {a, b, c}
                    out = bytearray(block)
                    for bit in flips:
                        out[bit // 8] ^= 1 << (bit % 8)
                    tried += 1
                    if check(out):
                        raise AssertionError(f"undetected {sorted(flips)}")
    return tried
