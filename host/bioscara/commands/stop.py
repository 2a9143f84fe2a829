"""`bioscara stop`: STOP every configured joint at once (also aborts homing)."""

from __future__ import annotations

import argparse

from ..session import Session

NAME = "stop"
HELP = "stop every joint at once (RPM 0; aborts a running homing)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    pass


def run(args: argparse.Namespace, session: Session) -> int:
    results = session.each_joint(list(session.config.joints), lambda joint: joint.stop(), "stopped")
    session.emit(results, "\n".join(f"{name}: {result}" for name, result in results.items()))
    return 0 if all(r == "stopped" for r in results.values()) else 1
