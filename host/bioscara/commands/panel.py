"""`bioscara panel`: the arm's control panel, full screen in the terminal or served to a browser."""

from __future__ import annotations

import argparse
import contextlib
import hmac
import os
import secrets
import shlex
import signal
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from aiohttp import web

from .. import interruption
from ..arm import Lifecycle
from ..errors import InvalidArgumentError
from ..session import Session

NAME = "panel"
HELP = "the arm's control panel (Textual): lifecycle, homing, jog, STOP, live plot; --web serves it to a browser"
EXAMPLES = (
    ('bioscara panel', 'the control panel on the shared simulated arm'),
    ('bioscara panel --bus smbus:1', "on a Raspberry Pi's joint bus (over SSH: `ssh -t pi@robot ...`)"),
    ('bioscara panel --web', 'the same panel in a browser, on http://127.0.0.1:8000'),
)
USES = ("bus", "protocol", "config", "take_over")  # a full-screen panel: no --json
LOCAL = "127.0.0.1"
PR_SET_PDEATHSIG = 1  # prctl(2)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--rate", type=float, default=100.0, metavar="HZ",
                        help="communicator frequency (default 100 Hz)")
    parser.add_argument("--web", action="store_true",
                        help="serve the panel to a browser instead of drawing it in this terminal")
    parser.add_argument("--host", default=LOCAL, metavar="ADDRESS",
                        help=f"with --web: the address to listen on (default {LOCAL}: this machine only)")
    parser.add_argument("--port", type=int, default=8000, help="with --web: the TCP port (default 8000)")
    parser.add_argument("--token", metavar="SECRET", help="with --web: require this secret in every request "
                        "(default: a random one, in the printed URL, when --host is not this machine)")


def run(args: argparse.Namespace, session: Session) -> int:
    if not 0 < args.rate <= 1000:
        raise InvalidArgumentError(f"--rate must be in (0, 1000] Hz, got {args.rate:g}")
    if args.web:
        return serve(args)
    served = "TEXTUAL_DRIVER" in os.environ  # textual-serve sets the driver
    if not sys.stdout.isatty() and not served:
        raise InvalidArgumentError("the panel needs a terminal (or use --web to serve it to a browser)")
    if served:
        die_with_the_server()
    from ..panel.app import PanelApp

    model = open_model(session, args.rate)
    session.drives(model.arm)
    app = PanelApp(model, end_on=interruption.SIGNALS)
    handlers = {signum: signal.getsignal(signum) for signum in interruption.SIGNALS}
    try:
        app.run()
    finally:
        for signum, handler in handlers.items():  # Textual's event loop left the defaults
            if handler is not None:
                signal.signal(signum, handler)
        try:
            if app.ended_by is not None:
                # to the command's own handler: Interrupted here, and any further signal held off
                signal.raise_signal(app.ended_by)
        finally:
            if model.arm.lifecycle is Lifecycle.ACTIVE:
                interruption.stop_arms([model.arm], session.err)
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
    """Serve the panel with textual-serve: every browser tab runs its own `bioscara panel`. Served
    beyond this machine, every request must carry the secret token (see `web_token`). No panel
    outlives the server: each exits with its server, and the server ends those still running."""
    from textual_serve.server import Server

    if not 0 < args.port < 65536:
        raise InvalidArgumentError(f"--port must be 1..65535, got {args.port}")
    command = [sys.executable, "-m", "bioscara.cli", "panel", "--rate", f"{args.rate:g}"]
    for option in ("bus", "config"):
        value = getattr(args, option, None)
        if value:
            command += [f"--{option}", value]
    local = args.host in (LOCAL, "localhost", "::1")
    token = args.token or (None if local else secrets.token_urlsafe(24))

    class PanelServer(Server):
        async def _make_app(self) -> web.Application:
            app = await super()._make_app()
            if token is not None:
                app.middlewares.append(web_token(token))
            return app

    where = "this machine only" if local else "every network it is on"
    url = f"http://{args.host}:{args.port}" + (f"/?token={token}" if token else "")
    print(f"bioscara panel: serving on {url} ({where}); each browser tab runs its own panel; Ctrl-C stops",
          flush=True)
    # `exec`: the shell textual-serve starts becomes the panel, whose parent is then this server.
    server = PanelServer("exec " + shlex.join(command), host=args.host, port=args.port, title="bioscara panel")
    try:
        server.serve()
    finally:
        end_children()
    return 0


TOKEN_COOKIE = "bioscara_panel_token"


def web_token(token: str) -> Any:
    """aiohttp middleware: a request passes with `?token=TOKEN` (the printed URL; the page then
    keeps it in a cookie for its websocket and files) or that cookie; any other gets 403 and
    reaches no panel, so it changes nothing."""
    @web.middleware
    async def check(request: web.Request, handler: Any) -> web.StreamResponse:
        if hmac.compare_digest(request.query.get("token", ""), token):
            response = await handler(request)
            if request.path == "/":
                response.set_cookie(TOKEN_COOKIE, token, httponly=True, samesite="Strict")
            return response
        if hmac.compare_digest(request.cookies.get(TOKEN_COOKIE, ""), token):
            return await handler(request)
        raise web.HTTPForbidden(text="bioscara panel: this panel needs its secret token: open the URL "
                                "`bioscara panel --web` printed\n")
    return check


def end_children(grace: float = 5.0) -> None:
    """SIGTERM the panels this server started that still run, then SIGKILL any left after `grace` s."""
    children = _children()
    for pid in children:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGTERM)
    deadline = time.monotonic() + grace
    while children and time.monotonic() < deadline:
        children = [pid for pid in children if _running(pid)]
        time.sleep(0.05)
    for pid in children:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
        _running(pid)


def _children() -> list[int]:
    """This process's children (Linux /proc; elsewhere none are known)."""
    pids: list[int] = []
    for task in Path("/proc/self/task").glob("*/children"):
        with contextlib.suppress(OSError):
            pids += [int(pid) for pid in task.read_text().split()]
    return pids


def _running(pid: int) -> bool:
    """Reap `pid` if it ended; True while it runs."""
    try:
        ended, _ = os.waitpid(pid, os.WNOHANG)
    except ChildProcessError:
        return False
    return ended == 0


def die_with_the_server() -> None:
    """In a panel the web server started: SIGTERM when the server dies, even by SIGKILL (Linux)."""
    with contextlib.suppress(OSError, AttributeError):
        import ctypes
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
        if os.getppid() == 1:  # the server died before the line above
            os.kill(os.getpid(), signal.SIGTERM)
