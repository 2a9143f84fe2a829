"""`bioscara info JOINT`: everything a joint reports about itself."""

from __future__ import annotations

import argparse
from dataclasses import asdict

from rich.table import Table

from ..errors import BioscaraError, IncorrectStateError, NotHomedError
from ..firmware import protocol as P
from ..firmware import protocol_v2 as V
from ..session import Session

NAME = "info"
HELP = ("identity, protocol, flags, position, velocity, last rejected frame and link statistics "
        "of a joint")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("joint", help="j1..j4")


def run(args: argparse.Namespace, session: Session) -> int:
    joint = session.joint(args.joint)
    jc = session.config.joints[args.joint]
    info: dict[str, object] = {"joint": args.joint, "address": f"0x{jc.address:02x}", "type": jc.type,
                               "reduction": jc.reduction, "limits": [jc.min, jc.max]}
    try:
        identity = joint.identity()
        info.update(firmware=identity.firmware_version, joint_id=identity.joint_id,
                    spec_hash=f"{identity.spec_hash:08x}", spec_matches=identity.spec_matches)
        reject = joint.last_reject()
        info["rejected_frames"] = reject.count
        if reject.count:
            info["last_rejected"] = reject.text
    except BioscaraError as exc:
        info["identity"] = f"unavailable ({exc.detail})"
        identity = None
    if session.protocol != "legacy" and identity is not None and identity.protocol >= V.PROTOCOL_V2:
        joint.use_v2()  # the rest is read over protocol v2
    elif session.protocol == "v2":
        raise IncorrectStateError("the joint does not serve protocol v2", joint=args.joint)
    info["protocol"] = joint.protocol
    try:
        info["position"] = joint.get_position()
    except NotHomedError:
        info["position"] = None
    info["velocity"] = joint.get_velocity()
    info["flags"] = P.describe_flags(joint.flags)
    info.update(homed=joint.is_homed(), enabled=joint.is_enabled(), stalled=joint.is_stalled(),
                busy=joint.is_busy())
    link = session.bus.stats.link(jc.address)
    info["link"] = {"transactions": link.transactions, "failed_attempts": link.failed_attempts}
    if joint.v2 is not None:
        info["v2_link"] = asdict(joint.v2.stats)
        joint.close()  # back to the legacy map for whoever comes next
    table = Table(title=f"{args.joint} on {session.bus.describe()}", show_header=False)
    for key, value in info.items():
        table.add_row(key, "not homed" if key == "position" and value is None else str(value))
    session.emit(info, table)
    return 0
