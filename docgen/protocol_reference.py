"""The protocol's tables, generated from the spec itself (firmware/joint/protocol.py, protocol_v2.py)."""

from __future__ import annotations

from bioscara.firmware.spec import protocol as P
from bioscara.firmware.spec import protocol_v2 as V

_KINDS = {P.U8: "u8", P.I32: "i32", P.F32: "f32", P.U16: "u16", P.U32: "u32", P.CHAR: "char"}


def _fields(fields: tuple[P.Field, ...], ranges: bool) -> str:
    parts = []
    for field in fields:
        text = f"{field.name}: {_KINDS[field.kind]}"
        if field.unit:
            text += f" {field.unit}"
        if ranges and field.kind in (P.U8, P.U16, P.F32) and (field.lo or field.hi):
            text += f" [{field.describe_range()}]"
        parts.append(text)
    return "<br>".join(parts).replace("|", "\\|") or "–"


def _flags(bits: int) -> str:
    return P.describe_flags(bits).replace("|", " ") if bits else ""


def registers() -> str:
    """The legacy register table: every register of the spec, its layouts and behaviour."""
    out = ["| addr | register | writes (payload) | reads (payload, then flags) | blocking | on acceptance | notes |",
           "|---|---|---|---|---|---|---|"]
    for reg in P.REGISTERS:
        effects = []
        if reg.sets:
            effects.append(f"sets {_flags(reg.sets)}")
        if reg.clears:
            effects.append(f"clears {_flags(reg.clears)}")
        if reg.zero_sets:
            effects.append(f"0 sets {_flags(reg.zero_sets)}")
        name = f"`{reg.name}`" if reg.supported else f"~~`{reg.name}`~~"
        doc = reg.doc.replace("|", "\\|")
        write = _fields(reg.write, ranges=True) if reg.writable else "–"
        read = _fields(reg.read, ranges=False) if reg.readable else ("flags" if reg.supported else "–")
        out.append(f"| 0x{reg.addr:02X} | {name} | {write} | {read} | {'yes' if reg.blocking else ''} | "
                   f"{', '.join(effects)} | {doc} |")
    return "\n".join(out) + "\n"


def flags() -> str:
    out = ["| bit | flag |", "|---|---|"]
    out += [f"| 0x{bit:02X} | `{name}` |" for bit, name in P.FLAG_NAMES]
    out.append(f"\nAt boot: `{P.describe_flags(P.FLAGS_AT_BOOT)}`. PING answers `{chr(P.ACK)}` (0x{P.ACK:02X}).")
    return "\n".join(out) + "\n"


def error_codes() -> str:
    out = ["| code | name | message |", "|---|---|---|"]
    out += [f"| {value} | `{name}` | {text} |" for value, name, text in P.ERROR_CODES]
    return "\n".join(out) + "\n"


def reject_reasons() -> str:
    out = ["| LASTERROR reason | text | v2 verdict |", "|---|---|---|"]
    for value, text in P.REJECT_REASONS:
        verdict = V.FROM_LEGACY[value] if value < len(V.FROM_LEGACY) else None
        shown = f"{verdict} ({V.reason_string(verdict)})" if verdict is not None else "–"
        out.append(f"| {value} | {text} | {shown} |")
    return "\n".join(out) + "\n"


def _offsets(fields: tuple[tuple[str, str, str, int], ...], starts: list[int], end: int) -> list[str]:
    rows = []
    for (name, kind, unit, scale), start, stop in zip(fields, starts, starts[1:] + [end]):
        where = str(start) if stop - start == 1 else f"{start}..{stop - 1}"
        scaled = f", 1/{scale}" if scale > 1 else ""
        rows.append(f"| {where} | `{name}` | {kind}{scaled} | {unit} |")
    return rows


def v2_map() -> str:
    """The v2 memory: mailbox and state block with their offsets, then the verdicts."""
    mailbox = [V.M_CMD, V.M_PAYLOAD, V.M_CRC, V.M_SEQ]
    state = [V.S_STATUS, V.S_POSITION, V.S_VELOCITY, V.S_ACK, V.S_CRC]
    out = [f"One memory of {V.MEM_SIZE} bytes, `mem_addrsize={V.MEM_ADDRSIZE}`: the mailbox at offset "
           f"{V.MAILBOX} ({V.MAILBOX_SIZE} bytes, the host writes it), the state block at {V.STATE} "
           f"({V.STATE_SIZE} bytes, the joint writes it). One transaction: {V.TRANSACTION_BITS} bit times.", "",
           "| offset | field | kind | meaning |", "|---|---|---|---|"]
    out += _offsets(V.MAILBOX_FIELDS, mailbox, V.MAILBOX + V.MAILBOX_SIZE)
    out += _offsets(V.STATE_FIELDS, state, V.STATE + V.STATE_SIZE)
    out += ["", "| verdict (status bits 4-6) | meaning | kind |", "|---|---|---|"]
    out += [f"| {value} | {text} | {'link' if value in V.LINK_REASONS else ('ok' if value == V.REASON_OK else 'command')} |"
            for value, text in V.REASONS]
    out += ["", f"A frame is new when its `seq` is 1..{V.SEQ_WINDOW - 1} ahead of `ack` (7-bit arithmetic); "
            f"a joint that hears nothing from its v2 host for {V.SILENCE_MS} ms serves the legacy map again."]
    return "\n".join(out) + "\n"


def facts() -> str:
    """The spec's identity: version, hash, frame sizes, wire cost."""
    return "\n".join([
        "| fact | value |", "|---|---|",
        f"| newest protocol served (`IDENTITY`) | {P.PROTOCOL_VERSION} |",
        f"| spec hash (CRC-32, `IDENTITY`) | `{P.SPEC_HASH:08x}` |",
        f"| longest command frame / reply | {P.MAX_FRAME} / {P.MAX_REPLY} bytes |",
        f"| one legacy register read or command | {P.wire_bits(1, 5)} bit times |",
        f"| one v2 exchange | {V.TRANSACTION_BITS} bit times |",
    ]) + "\n"
