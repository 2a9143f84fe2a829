"""`bioscara enable` / `bioscara disable`: energize joints with their configured currents and limits, or freewheel."""

from __future__ import annotations

import argparse

from ..arm import activate_joint
from ..session import Session


def add_joint_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("joints", nargs="*", default=["all"], metavar="JOINT", help="j1..j4 or all (default)")


def selected(session: Session, names: list[str]) -> list[str]:
    return list(session.config.joints) if "all" in names else names


def enable(args: argparse.Namespace, session: Session) -> int:
    done = []
    for name in selected(session, args.joints):
        joint = session.joint(name)
        activate_joint(joint, session.config.joints[name])
        done.append({"joint": name, "homed": joint.is_homed()})
    session.emit(done, "\n".join(f"{d['joint']}: enabled{'' if d['homed'] else ' (not homed)'}" for d in done))
    return 0


def disable(args: argparse.Namespace, session: Session) -> int:
    results = session.each_joint(selected(session, args.joints), lambda joint: joint.disable(),
                                 "disabled (freewheeling)")
    session.emit([{"joint": name, "result": result} for name, result in results.items()],
                 "\n".join(f"{name}: {result}" for name, result in results.items()))
    return 0 if all(not r.startswith("FAILED") for r in results.values()) else 1
