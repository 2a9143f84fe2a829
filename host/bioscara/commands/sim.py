"""`bioscara sim --pty`: the configured simulated joints in real time behind pseudo-terminals."""

from __future__ import annotations

import argparse
import sys

from rich.table import Table

from ..hardware import sim_joint_specs
from ..session import Session

NAME = "sim"
HELP = ("run the simulated arm in real time: a HIL bridge pseudo-terminal for `--bus serial:PATH` "
        "and one debug console per joint for `bioscara console PATH`; Ctrl-C stops it")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--pty", action="store_true", default=True,
                        help="serve on pseudo-terminals (the default, and the only transport so far)")


def run(args: argparse.Namespace, session: Session) -> int:
    from ..sim_server import SimServer

    config = session.config
    server = SimServer(sim_joint_specs(config), seed=config.sim.seed, speed_hz=config.bus.speed_hz)
    try:
        paths = {"bridge": server.bridge_path, "joints": server.joint_paths}
        table = Table("serves", "path", "use with", box=None)
        table.add_row("HIL bridge", server.bridge_path, f"--bus serial:{server.bridge_path}")
        for joint, path in server.joint_paths.items():
            table.add_row(f"{joint} debug console", path, f"bioscara console {path}")
        session.emit(paths, table)
        sys.stdout.flush()  # a parent process reads the paths through a pipe
        try:
            server.serve_forever()
        except KeyboardInterrupt:
            pass  # the way to stop it
    finally:
        server.close()
    return 0
