"""`bioscara demo`: the simulated pick and place."""

from __future__ import annotations

import argparse

from ..session import Session

NAME = "demo"
HELP = "simulated pick and place: configure, activate, home, pick, place (no hardware needed)"
USES = ("config", "json")  # always the simulator in this process, whatever the bus


def add_arguments(parser: argparse.ArgumentParser) -> None:
    pass


def run(args: argparse.Namespace, session: Session) -> int:
    from .. import demo_scenario
    steps = demo_scenario.run(session.config, session.console)
    if session.json:
        session.emit([{"step": s.name, "targets": s.targets, "final": s.reached,
                       "gripper_target": s.gripper_target, "gripper": s.gripper} for s in steps])
    return 0
