"""`bioscara scan`: which addresses answer, with identity, firmware version, spec hash and flags."""

from __future__ import annotations

import argparse

from rich.table import Table

from ..errors import BioscaraError
from ..firmware import protocol as P
from ..firmware import protocol_v2 as V
from ..joint import Joint
from ..session import Session

NAME = "scan"
HELP = "list the devices that answer on the bus, with identity, version, spec hash and flags"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    pass


def probe(session: Session, addr: int) -> dict[str, object]:
    """What one answering address is: a joint of this project, an original joint, or unknown."""
    names = {jc.address: name for name, jc in session.config.joints.items()}
    entry: dict[str, object] = {"address": addr, "joint": names.get(addr)}
    joint = Joint(names.get(addr, f"0x{addr:02x}"), addr, session.bus)
    try:
        joint.init()
    except BioscaraError as exc:
        entry.update(kind="unknown device", problem=str(exc))
        return entry
    entry["flags"] = P.describe_flags(joint.flags)
    try:
        identity = joint.identity()
    except BioscaraError:
        entry["kind"] = "joint (original firmware: no identity register)"
        return entry
    entry.update(kind="joint", firmware=identity.firmware_version, joint_id=identity.joint_id,
                 protocol=identity.protocol, spec_hash=f"{identity.spec_hash:08x}",
                 spec_matches=identity.spec_matches,
                 protocols="legacy+v2" if identity.protocol >= V.PROTOCOL_V2 else "legacy")
    if not identity.spec_matches:
        entry["problem"] = (f"spec hash {identity.spec_hash:08x} differs from this host's "
                            f"{P.SPEC_HASH:08x}: firmware and host were built from different protocol specs")
    return entry


def run(args: argparse.Namespace, session: Session) -> int:
    found = [probe(session, addr) for addr in session.bus.scan()]
    table = Table(title=f"devices on {session.bus.describe()}")
    for column in ("address", "joint", "kind", "firmware", "protocols", "spec hash", "flags", "problem"):
        table.add_column(column)
    for e in found:
        spec = e.get("spec_hash", "")
        if spec:
            spec = f"{spec} {'ok' if e['spec_matches'] else 'MISMATCH'}"
        table.add_row(f"0x{e['address']:02x}", str(e["joint"] or "-"), str(e["kind"]), str(e.get("firmware", "")),
                      str(e.get("protocols", "")), str(spec), str(e.get("flags", "")), str(e.get("problem", "")))
    session.emit(found, table if found else "no device answered")
    return 0 if found and not any("problem" in e for e in found) else 1
