"""`bioscara info JOINT`: everything a joint reports about itself."""

from __future__ import annotations

import argparse
from typing import Any

from rich.table import Table

from .. import report
from ..errors import BioscaraError, NotHomedError
from ..session import Session
from .options import one_joint

NAME = "info"
HELP = ("identity, flags, position, velocity, last rejected frame and link statistics of a joint (read "
        "only: beside a program that commands the arm, what that program last read)")
USES = ("bus", "protocol", "config", "json")  # it only watches: nothing to take over


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("joint", type=one_joint, help="j1..j4")


def run(args: argparse.Namespace, session: Session) -> int:
    joint = session.joint(args.joint, watch=True)  # read only: beside whatever commands the arm
    jc = session.config.joints[args.joint]
    info: dict[str, Any] = {**report.joint_ref(args.joint, jc), "type": jc.type, "reduction": jc.reduction,
                            "limits": [jc.min, jc.max]}
    try:
        identity = joint.identity()
        info.update(protocol_version=identity.protocol, firmware=identity.firmware_version,
                    joint_id=identity.joint_id, spec_hash=f"{identity.spec_hash:08x}",
                    spec_matches=identity.spec_matches)
        reject = joint.last_reject()
        info["rejected_frames"] = reject.count
        info["last_rejected"] = reject.text if reject.count else None
    except BioscaraError as exc:
        info["identity_error"] = exc.detail
    try:
        info["position"] = joint.get_position()
    except NotHomedError:
        info["position"] = None
    info["velocity"] = joint.get_velocity()
    holder = getattr(joint.link, "holder", None)
    info["commanded_by"] = None if holder is None else {"pid": holder.pid, "program": holder.program}
    info["flags"] = report.flags(joint.flags)
    info.update(homed=joint.is_homed(), enabled=joint.is_enabled(), stalled=joint.is_stalled(),
                busy=joint.is_busy())
    link = session.bus.stats.link(jc.address)
    info["link"] = {"transactions": link.transactions, "failed_attempts": link.failed_attempts}
    session.emit(info, _table(info, jc, session))
    return 0


def _table(info: dict[str, Any], jc: Any, session: Session) -> Table:
    u = info["unit"]
    rows = [("address", report.address(info["address"])), ("type", f"{info['type']} (positions in {u})"),
            ("reduction", f"{info['reduction']:g} motor rad per {u}"),
            ("limits", f"{jc.min:g}..{jc.max:g} {u}")]
    if "identity_error" in info:
        rows.append(("identity", f"unavailable ({info['identity_error']})"))
    else:
        rows += [("firmware", f"{info['firmware']} (protocol version {info['protocol_version']}, "
                  f"joint id {info['joint_id']})"),
                 ("spec hash", f"{info['spec_hash']} {'ok' if info['spec_matches'] else 'MISMATCH'}"),
                 ("rejected frames", f"{info['rejected_frames']}"
                  + (f" (last: {info['last_rejected']})" if info["last_rejected"] else ""))]
    rows += [("commanded by", "no program" if info["commanded_by"] is None else
              f"pid {info['commanded_by']['pid']} ({info['commanded_by']['program']}): its latest reading"),
             ("position", "not homed" if info["position"] is None else report.value(info["position"], jc)),
             ("velocity", report.value(info["velocity"], jc, per_second=True)),
             ("flags", "|".join(info["flags"]) or "-"),
             ("state", ", ".join(f"{k}" if info[k] else f"not {k}" for k in ("homed", "enabled", "stalled", "busy"))),
             ("link", f"{info['link']['transactions']} transactions, {info['link']['failed_attempts']} failed attempts")]
    table = Table(title=f"{info['joint']} on {session.bus.describe()}", show_header=False)
    for key, value in rows:
        table.add_row(key, value)
    return table
