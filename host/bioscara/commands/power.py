"""`bioscara enable` / `bioscara disable`: energize joints with their configured currents and limits, or freewheel."""

from __future__ import annotations

import argparse

from ..session import Session


def add_joint_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("joints", nargs="*", default=["all"], metavar="JOINT", help="j1..j4 or all (default)")


def selected(session: Session, names: list[str]) -> list[str]:
    return list(session.config.joints) if "all" in names else names


def enable(args: argparse.Namespace, session: Session) -> int:
    done = []
    for name in selected(session, args.joints):
        joint = session.joint(name)
        jc = session.config.joints[name]
        joint.enable(jc.drive_current, jc.hold_current)
        if jc.stall_threshold > 0:
            joint.enable_stallguard(jc.stall_threshold)
        joint.set_max_acceleration(jc.max_acceleration)
        joint.set_max_velocity(jc.max_velocity)
        done.append({"joint": name, "homed": joint.is_homed()})
    session.emit(done, "\n".join(f"{d['joint']}: enabled{'' if d['homed'] else ' (not homed)'}" for d in done))
    return 0


def disable(args: argparse.Namespace, session: Session) -> int:
    names = selected(session, args.joints)
    for name in names:
        session.joint(name).disable()
    session.emit([{"joint": name, "enabled": False} for name in names],
                 "\n".join(f"{name}: disabled (freewheeling)" for name in names))
    return 0
