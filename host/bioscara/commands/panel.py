"""`bioscara panel`: the arm's control panel, full screen in the terminal or served to a browser."""

from __future__ import annotations

import argparse
import os
import shlex
import sys
from dataclasses import replace

from ..errors import InvalidArgumentError
from ..session import Session

NAME = "panel"
HELP = "the arm's control panel (Textual): lifecycle, homing, jog, STOP, live plot; --web serves it to a browser"
USES = ("bus", "protocol", "config", "take_over")  # a full-screen panel: no --json
LOCAL = "127.0.0.1"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--rate", type=float, default=100.0, metavar="HZ",
                        help="communicator frequency (default 100 Hz)")
    parser.add_argument("--web", action="store_true",
                        help="serve the panel to a browser instead of drawing it in this terminal")
    parser.add_argument("--host", default=LOCAL, metavar="ADDRESS",
                        help=f"with --web: the address to listen on (default {LOCAL}: this machine only)")
    parser.add_argument("--port", type=int, default=8000, help="with --web: the TCP port (default 8000)")


def run(args: argparse.Namespace, session: Session) -> int:
    if not 0 < args.rate <= 1000:
        raise InvalidArgumentError(f"--rate must be in (0, 1000] Hz, got {args.rate:g}")
    if args.web:
        return serve(args)
    if not sys.stdout.isatty() and "TEXTUAL_DRIVER" not in os.environ:  # textual-serve sets the driver
        raise InvalidArgumentError("the panel needs a terminal (or use --web to serve it to a browser)")
    from ..panel.app import PanelApp

    model = open_model(session, args.rate)
    try:
        PanelApp(model).run()
    finally:
        model.close()
    return 0


def open_model(session: Session, rate: float, *, threaded: bool = True):  # type: ignore[no-untyped-def]
    """The panel's model on the session's configuration; the simulator runs in real time, since the
    panel's communicator cycles at wall-clock pace."""
    from ..hardware import open_arm, open_arm_bus, open_gripper
    from ..panel.model import PanelModel

    config = session.config
    if config.bus_url.startswith("sim:") and threaded:
        config = replace(config, sim=replace(config.sim, realtime=True))
    bus = open_arm_bus(config)
    clock = bus.monotonic
    arm = open_arm(config, bus, session.protocol, take_over=bool(getattr(session.args, "take_over", False)))
    return PanelModel(config, arm, open_gripper(config, clock), frequency=rate, threaded=threaded)


def serve(args: argparse.Namespace) -> int:
    """Serve the panel with textual-serve: every browser tab runs its own `bioscara panel`."""
    from textual_serve.server import Server

    if not 0 < args.port < 65536:
        raise InvalidArgumentError(f"--port must be 1..65535, got {args.port}")
    command = [sys.executable, "-m", "bioscara.cli", "panel", "--rate", f"{args.rate:g}"]
    for option in ("bus", "config"):
        value = getattr(args, option, None)
        if value:
            command += [f"--{option}", value]
    where = "this machine only" if args.host in (LOCAL, "localhost", "::1") else "every network it is on"
    print(f"bioscara panel: serving on http://{args.host}:{args.port} ({where}); "
          f"each browser tab runs its own panel; Ctrl-C stops", flush=True)
    Server(shlex.join(command), host=args.host, port=args.port, title="bioscara panel").serve()
    return 0
