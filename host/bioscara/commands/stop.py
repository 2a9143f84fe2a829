"""`bioscara stop`: STOP every configured joint at once (also aborts homing)."""

from __future__ import annotations

import argparse

from ..errors import BioscaraError
from ..joint import Joint
from ..session import Session

NAME = "stop"
HELP = "stop every joint at once (RPM 0; aborts a running homing)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    pass


def run(args: argparse.Namespace, session: Session) -> int:
    results = {}
    for name, jc in session.config.joints.items():
        joint = Joint(name, jc.address, session.bus)
        try:
            joint.init()
            joint.stop()
            results[name] = "stopped"
        except BioscaraError as exc:  # stop the others even if one does not answer
            results[name] = f"FAILED: {exc}"
    session.emit(results, "\n".join(f"{name}: {result}" for name, result in results.items()))
    return 0 if all(r == "stopped" for r in results.values()) else 1
