"""`bioscara enable` / `bioscara disable`: energize joints with their configured currents and limits, or freewheel."""

from __future__ import annotations

import argparse
from collections.abc import Callable

from .. import report
from ..arm import activate_joint
from ..errors import BioscaraError
from ..joint import Joint
from ..session import Session
from .options import joint_name


def add_joint_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("joints", nargs="*", type=joint_name, default=["all"], metavar="JOINT",
                        help="j1..j4 or all (default)")


def selected(session: Session, names: list[str]) -> list[str]:
    return list(session.config.joints) if "all" in names else list(dict.fromkeys(names))


def each_joint(session: Session, names: list[str], action: Callable[[Joint], str]) -> int:
    """`action` on every named joint, going on past one that fails; prints the outcomes (one shape
    for enable, disable and stop); exit status 1 if any failed."""
    outcomes = []
    for name in selected(session, names):
        jc = session.config.joints.get(name)
        try:
            result = action(session.joint(name))
        except BioscaraError as exc:
            if jc is None:
                raise
            outcomes.append(report.outcome(name, jc, error=exc.detail))
        else:
            outcomes.append(report.outcome(name, session.config.joints[name], result))
    session.emit(outcomes, "\n".join(f"{o['joint']} ({report.address(o['address'])}): "
                                     + (o["result"] if o["ok"] else f"FAILED: {o['error']}") for o in outcomes))
    return 0 if all(o["ok"] for o in outcomes) else 1


def enable(args: argparse.Namespace, session: Session) -> int:
    def energize(joint: Joint) -> str:
        activate_joint(joint, session.config.joints[joint.name])
        return "enabled" if joint.is_homed() else "enabled (not homed)"
    return each_joint(session, args.joints, energize)


def disable(args: argparse.Namespace, session: Session) -> int:
    def freewheel(joint: Joint) -> str:
        joint.disable()
        return "disabled (freewheeling)"
    return each_joint(session, args.joints, freewheel)
