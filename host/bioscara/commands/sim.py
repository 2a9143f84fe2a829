"""`bioscara sim [start|status|stop]`: the shared simulated arm that the `sim:` bus reaches;
`bioscara sim --pty`: a separate simulated arm in the foreground, behind pseudo-terminals only."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from rich.console import Group
from rich.table import Table
from rich.text import Text

from .. import sim_service
from ..errors import InvalidArgumentError
from ..hardware import sim_joint_specs
from ..paths import default_state_dir
from ..session import Session
from .options import non_negative

NAME = "sim"
HELP = ("the shared simulated arm behind the default `sim:` bus: start it (also done by the first "
        "command that needs it), show it, stop it (its state is kept until then); --pty: a separate "
        "arm in the foreground behind pseudo-terminals, Ctrl-C stops it")
EXAMPLES = (
    ('bioscara sim', 'start the shared simulated arm (or show it) and its terminals'),
    ('bioscara sim stop', 'stop it (its state goes with it)'),
    ('bioscara sim --pty', 'a separate arm in the foreground behind pseudo-terminals; Ctrl-C stops it'),
)
USES = ("config", "json")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("action", nargs="?", choices=("start", "status", "stop"), default="start",
                        help="start (default: start unless running, then show it), status, stop")
    parser.add_argument("--idle-exit", type=non_negative("min"), metavar="MIN",
                        help="a started arm ends by itself after MIN minutes with no client connected and "
                        "no joint moving (0: never; default: the config's sim.idle_exit_min, 15)")
    parser.add_argument("--pty", action="store_true",
                        help="instead: run a separate simulated arm in the foreground, behind a HIL bridge "
                        "pseudo-terminal (for --bus serial:PATH) and one debug console per joint")


def run(args: argparse.Namespace, session: Session) -> int:
    if args.pty:
        if args.action != "start":
            raise InvalidArgumentError(f"--pty runs an arm in the foreground; `sim {args.action}` is for the shared one")
        if args.idle_exit is not None:
            raise InvalidArgumentError("--idle-exit is for the shared arm; a --pty arm runs until Ctrl-C")
        return _foreground(session)
    if args.idle_exit is not None and args.action != "start":
        raise InvalidArgumentError(f"--idle-exit is for `sim start`, not `sim {args.action}`")
    state_dir = default_state_dir()
    if args.action == "stop":
        before = sim_service.status(state_dir)
        stopped = sim_service.stop(state_dir)
        session.emit({"running": False, "stopped": stopped},
                     f"stopped the simulated arm (pid {before['pid']})" if stopped and before
                     else "no simulated arm was running")
        return 0
    started = False
    if args.action == "start":
        config = session.config
        minutes = config.sim.idle_exit_min if args.idle_exit is None else args.idle_exit
        started = sim_service.start(state_dir, sim_joint_specs(config), seed=config.sim.seed,
                                    speed_hz=config.bus.speed_hz, idle_exit_s=minutes * 60.0 or None)
    status = sim_service.status(state_dir)
    if status is None:
        session.emit({"running": False}, "no simulated arm is running (`bioscara sim` starts one)")
        return 1
    data = _describe(status, started)
    session.emit(data, _render(data))
    if args.idle_exit is not None and not started and status.get("idle_exit_s") != (args.idle_exit * 60.0 or None):
        session.err("warning: --idle-exit applies to an arm this command starts; this one was already "
                    "running (`bioscara sim stop` first to change it)")
    return 0


def _describe(status: dict[str, Any], started: bool) -> dict[str, Any]:
    consoles = status.get("consoles", {})
    return {"running": True, "started": started, "pid": status["pid"], "socket": status["socket"],
            "uptime_s": status["uptime_s"], "clients": status["clients"] - 1,  # not counting this one
            "idle_exit_s": status.get("idle_exit_s"),
            "bridge": status["bridge"],
            "joints": {spec["firmware_joint"].lower(): {"address": spec["address"],
                                                        "console": consoles.get(spec["firmware_joint"])}
                       for spec in status["specs"]}}


def _render(data: dict[str, Any]) -> Group:
    idle = data["idle_exit_s"]
    ends = "" if idle is None else f", or {idle / 60:g} min without a client and with no joint moving"
    head = Text(f"simulated arm {'started' if data['started'] else 'running'}: pid {data['pid']}, "
                f"up {data['uptime_s']:.0f} s, {data['clients']} other client(s); `bioscara sim stop` ends it{ends}")
    table = Table(box=None)
    for column in ("serves", "at", "use with"):
        table.add_column(column)
    table.add_row("the sim: bus", data["socket"], "every command (the default bus)")
    table.add_row("HIL bridge", data["bridge"], f"--bus serial:{data['bridge']}")
    for joint, entry in data["joints"].items():
        table.add_row(f"{joint} (0x{entry['address']:02x}) debug console", str(entry["console"]),
                      f"bioscara console {entry['console']}")
    return Group(head, table)


def _foreground(session: Session) -> int:
    from ..sim_server import SimServer

    config = session.config
    server = SimServer(sim_joint_specs(config), seed=config.sim.seed, speed_hz=config.bus.speed_hz)
    try:
        paths = {"bridge": server.bridge_path,
                 "joints": {joint.lower(): path for joint, path in server.joint_paths.items()}}
        table = Table("serves", "path", "use with", box=None)
        table.add_row("HIL bridge", server.bridge_path, f"--bus serial:{server.bridge_path}")
        for joint, path in paths["joints"].items():
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
