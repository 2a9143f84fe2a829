"""`bioscara stop`: STOP every configured joint at once (also aborts homing)."""

from __future__ import annotations

import argparse

from ..joint import Joint
from ..session import Session
from .power import each_joint

NAME = "stop"
HELP = "stop every joint at once (RPM 0; aborts a running homing)"
EXAMPLES = (
    ('bioscara stop', 'STOP every joint at once'),
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    pass


def run(args: argparse.Namespace, session: Session) -> int:
    def stop(joint: Joint) -> str:
        joint.stop()
        return "stopped"
    return each_joint(session, ["all"], stop)
