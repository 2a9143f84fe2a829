"""The hook for the chip comparison of protocol v2: frames and the exact reply bytes the simulator
gives for them, to be replayed against the emulated Pico (tests/chip/) and compared byte by byte.

`sim_vectors()` runs a fixed script against the real firmware (core + ProtocolSwitch + MemLink on
the fake mem-mode target) of joint J1, its motor at rest at angle 0: the legacy switch to v2, NONE
polls, SETUP, a bad CRC, a stale sequence number, a truncated and an overlong frame, STOP, and the
switch back. Each `Vector` is one transaction (write, read length) and the reply; between
transactions the joint's main loop runs at least once (`settle_ms`). A chip test feeds the same
transactions to `chip.i2c.JointBusClient.transfer` with `gap_us = settle_ms * 1000` and asserts
`compare(vectors, replies) == []`; the chip joint must be booted (its motor driver and encoder
emulated) and at rest at angle 0, so that position and velocity are 0 as here.
"""

from __future__ import annotations

from dataclasses import dataclass

from bioscara.firmware.spec import protocol as P
from bioscara.firmware.spec import protocol_v2 as V

from v2rig import V2Rig


# After a transaction that switches the protocol: the switch may start with a garbage
# collection (firmware/joint/links/memmap_v2.py `_make_room`, about 20 ms on the chip).
SWITCH_MS = 60


@dataclass(frozen=True)
class Vector:
    write: bytes
    read_len: int
    reply: bytes
    note: str
    settle_ms: int = 2


def sim_vectors(rounds: int = 1) -> list[Vector]:
    """The script's transactions, `rounds` times over on one joint (from the second round on the
    joint is enabled: SETUP of the first round)."""
    rig = V2Rig()
    out: list[Vector] = []
    for _ in range(rounds):
        _script(rig, out)
    return out


def _script(rig: V2Rig, out: list[Vector]) -> None:

    def xfer(write: bytes, read_len: int, note: str, settle_ms: int = 2) -> None:
        out.append(Vector(write, read_len, rig.xfer(write, read_len), note, settle_ms))
        rig.run_ms(2)

    address = rig.address
    xfer(bytes([P.IDENTITY]), P.register("IDENTITY").rsize + 1, "legacy IDENTITY")
    xfer(bytes([P.PROTOCOL]) + P.register("PROTOCOL").encode(V.PROTOCOL_V2), 1, "legacy PROTOCOL 2",
         SWITCH_MS)
    seq = 0

    def frame(cmd: int, payload: bytes = b"", step: int = 1) -> bytes:
        nonlocal seq
        seq = (seq + step) & V.SEQ_MASK
        return V.encode_frame(address, cmd, payload, seq)

    xfer(frame(V.CMD_NONE), V.STATE_SIZE, "v2 NONE (first frame)")
    xfer(frame(V.CMD_NONE), V.STATE_SIZE, "v2 NONE")
    xfer(frame(P.SETUP, P.register("SETUP").encode(40, 20, 0, 0)), V.STATE_SIZE, "v2 SETUP 40 20")
    xfer(frame(V.CMD_NONE), V.STATE_SIZE, "v2 NONE: SETUP's verdict, NOTENABLED clear")
    bad = bytearray(frame(P.SETCURRENT, P.register("SETCURRENT").encode(30)))
    bad[V.M_CRC] ^= 0x01
    xfer(bytes(bad), V.STATE_SIZE, "v2 SETCURRENT with a bad CRC")
    xfer(frame(V.CMD_NONE, step=0), V.STATE_SIZE, "v2 NONE with the bad frame's seq: verdict CRC shown")
    xfer(frame(V.CMD_NONE, step=-5), V.STATE_SIZE, "v2 NONE 5 behind: stale")
    seq = (seq + 5) & V.SEQ_MASK
    xfer(frame(V.CMD_NONE), V.STATE_SIZE, "v2 NONE: SEQUENCE shown")
    xfer(frame(V.CMD_NONE)[:4], V.STATE_SIZE, "v2 truncated frame (the read starts at offset 4)")
    xfer(frame(V.CMD_NONE) + b"\x00", V.STATE_SIZE, "v2 overlong frame (the read starts at offset 8)")
    xfer(frame(V.CMD_NONE), V.STATE_SIZE, "v2 NONE: FRAME shown")
    xfer(frame(P.STOP, P.register("STOP").encode(0)), V.STATE_SIZE, "v2 STOP")
    legacy = frame(P.PROTOCOL, P.register("PROTOCOL").encode(V.PROTOCOL_LEGACY))
    xfer(legacy, V.STATE_SIZE, "v2 PROTOCOL 1")
    xfer(legacy, V.STATE_SIZE, "v2 PROTOCOL 1 again: its verdict (the joint switches after this read)",
         SWITCH_MS)
    xfer(bytes([P.PING]), 2, "legacy PING again")


def wrapped(vector: Vector) -> int:
    """Where a v2 read that runs past the end of the memory wraps to the mailbox: from there its
    bytes depend on whether the END_WRITE handler (a soft IRQ) emptied the mailbox before the read
    got there, which the chip's scheduler decides, not the protocol (no host reads past the end)."""
    if not vector.note.startswith("v2"):
        return len(vector.reply)
    return V.MEM_SIZE - len(vector.write) % V.MEM_SIZE


def compare(vectors: list[Vector], replies: list[bytes]) -> list[str]:
    """Every transaction whose reply differs, with the differing byte offsets (bytes a read got by
    wrapping past the end of the memory aside: `wrapped`)."""
    problems = []
    for vector, reply in zip(vectors, replies):
        end = wrapped(vector)
        if len(reply) != len(vector.reply) or reply[:end] != vector.reply[:end]:
            offsets = [i for i in range(max(len(reply), len(vector.reply)))
                       if reply[i:i + 1] != vector.reply[i:i + 1]]
            problems.append(f"{vector.note}: bytes {offsets} {reply.hex()} != {vector.reply.hex()}")
    if len(replies) != len(vectors):
        problems.append(f"{len(replies)} replies for {len(vectors)} transactions")
    return problems
