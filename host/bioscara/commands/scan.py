"""`bioscara scan`: what answers on the bus, checked against the configuration (a bring-up check).

Every address that answers is probed (identity, firmware version, spec hash, flags); then what
answers is compared with the configured joints: a configured joint that does not answer is
missing, a joint whose IDENTITY names another joint than the one configured at its address is
misaddressed (the configured joint found at another address is reported there), and a device
that is not in the configuration is unexpected. Any problem makes the exit status 1.
"""

from __future__ import annotations

import argparse
from typing import Any

from rich.table import Table

from .. import report
from ..errors import BioscaraError
from ..firmware.spec import protocol as P
from ..firmware.spec import protocol_v2 as V
from ..joint import Joint
from ..session import Session

NAME = "scan"
HELP = ("list what answers on the bus (identity, firmware, spec hash, flags) and check it against the "
        "configuration: missing, misaddressed and unexpected joints are problems (exit status 1)")
COLUMNS = ("address", "joint", "kind", "firmware", "protocols", "spec hash", "flags", "problems")
USES = ("bus", "config", "json")  # it reports the protocols each joint serves: no --protocol to choose one


def add_arguments(parser: argparse.ArgumentParser) -> None:
    pass


def probe(session: Session, addr: int, configured: str | None) -> dict[str, Any]:
    """What one answering address is: a joint of this project, an original joint, or unknown."""
    entry: dict[str, Any] = {"address": addr, "joint": configured, "kind": "unknown device",
                             "answers": True, "problems": []}
    joint = Joint(configured or report.address(addr), addr, session.bus, watch=True)  # read only
    try:
        joint.init()
    except BioscaraError as exc:
        entry["problems"].append(f"does not answer as a joint ({exc.detail})")
        return entry
    entry["flags"] = report.flags(joint.flags)
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
        entry["problems"].append(f"spec hash {identity.spec_hash:08x} differs from this host's {P.SPEC_HASH:08x}: "
                                 "firmware and host were built from different protocol specs")
    return entry


def check(session: Session, found: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Add the configuration's view to the probed entries: missing, misaddressed, unexpected."""
    joints = session.config.joints
    by_addr = {e["address"]: e for e in found}
    by_identity = {f"j{e['joint_id']}": e for e in found if "joint_id" in e}
    entries = list(found)
    for name, jc in joints.items():
        entry = by_addr.get(jc.address)
        elsewhere = by_identity.get(name)
        if entry is None:
            where = (f"; IDENTITY says {name} answers at {report.address(elsewhere['address'])}"
                     if elsewhere is not None else " (not powered, not wired, or set to another address)")
            entries.append({"address": jc.address, "joint": name, "kind": "missing", "answers": False,
                            "problems": [f"{name} is configured at {report.address(jc.address)} but nothing "
                                         f"answers there{where}"]})
        elif "joint_id" in entry and entry["joint_id"] != int(name[1:]):
            entry["problems"].append(f"misaddressed: IDENTITY says joint {entry['joint_id']} (j{entry['joint_id']}) "
                                     f"answers at {report.address(jc.address)}, where the configuration has {name}")
    configured = {jc.address for jc in joints.values()}
    for entry in found:
        if entry["address"] in configured:
            continue
        ident = entry.get("joint_id")
        if ident is not None and f"j{ident}" in joints:
            name = f"j{ident}"
            entry["problems"].append(f"misaddressed: {name} (by IDENTITY) answers here, but the configuration "
                                     f"has it at {report.address(joints[name].address)}")
        else:
            entry["problems"].append("unexpected: not in the configuration")
    return sorted(entries, key=lambda e: e["address"])


def run(args: argparse.Namespace, session: Session) -> int:
    names = {jc.address: name for name, jc in session.config.joints.items()}
    found = [probe(session, addr, names.get(addr)) for addr in session.bus.scan()]
    entries = check(session, found)
    table = Table(title=f"devices on {session.bus.describe()}")
    for column in COLUMNS:
        table.add_column(column, overflow="fold")
    for e in entries:
        spec = e.get("spec_hash", "")
        if spec:
            spec = f"{spec} {'ok' if e['spec_matches'] else 'MISMATCH'}"
        table.add_row(report.address(e["address"]), e["joint"] or "-", e["kind"], e.get("firmware", ""),
                      e.get("protocols", ""), spec,
                      "|".join(e.get("flags", [])) or ("-" if e["answers"] else ""), "; ".join(e["problems"]),
                      style="red" if e["problems"] else None)
    session.emit(entries, table if entries else "nothing answers and nothing is configured")
    return 1 if not found or any(e["problems"] for e in entries) else 0
