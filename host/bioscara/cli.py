"""The `bioscara` command line: one module per command in `bioscara.commands`.

A command module may declare `USES`, the common options it takes (`bus`, `protocol`, `config`,
`json`, `take_over`; all five by default): options a command would ignore are refused. The common options and
`-v` are accepted before the command as well as after it. Failures the user can act on print one line and exit 2
(usage and configuration errors) or 1 (device and bus errors); nothing prints a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from collections.abc import Sequence

from . import __version__, interruption
from .arm import PROTOCOLS
from .bus import Bus
from .commands import COMMANDS
from .errors import BioscaraError, ConfigError, InvalidArgumentError
from .session import Session

ALL_OPTIONS = ("bus", "protocol", "config", "json", "take_over")
TOP_DEFAULTS = {"bus": None, "protocol": "auto", "config": None, "json": False, "take_over": False}  # what "not given" looks like
USAGE, DEVICE, INTERNAL, BROKEN_PIPE = 2, 1, 70, 141  # exit statuses (141: 128 + SIGPIPE)


class _Parser(argparse.ArgumentParser):
    """Usage errors in one line, like every other error."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(USAGE, f"error: {message} (`{self.prog} --help` shows the usage)\n")


def _common(uses: Sequence[str], top: bool) -> argparse.ArgumentParser:
    """The common options; after the command their defaults are SUPPRESS, so a value given
    before the command is kept."""
    common = _Parser(add_help=False)
    suppress = {} if top else {"default": argparse.SUPPRESS}
    if "bus" in uses:
        common.add_argument("--bus", metavar="URL", help="smbus:1, blinka:, serial:/dev/ttyACM0, sim: (the "
                            "shared simulated arm) or sim:virtual (default: $BIOSCARA_BUS, else the config's bus)")
    if "protocol" in uses:
        common.add_argument("--protocol", choices=PROTOCOLS, help="joint protocol: auto (v2 where the joint "
                            "serves it), legacy or v2 (default: auto)", **({"default": "auto"} if top else suppress))
    if "config" in uses:
        common.add_argument("--config", metavar="FILE", help="arm configuration (TOML; default: "
                            "$XDG_CONFIG_HOME/bioscara/arm.toml if it exists, else the shipped j1-j4 configuration)")
    if "take_over" in uses:
        common.add_argument("--take-over", action="store_true", help="if another program commands the arm, "
                            "stop it and command (default: refuse, naming it)",
                            **({"default": False} if top else suppress))
    if "json" in uses:
        common.add_argument("--json", action="store_true", help="machine-readable output (JSON)",
                            **({"default": False} if top else suppress))
    common.add_argument("-v", "--verbose", action="count", help="more log output",
                        **({"default": 0} if top else suppress))
    return common


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="bioscara", description="Bioscara SCARA arm tools",
                     parents=[_common(ALL_OPTIONS, top=True)])
    parser.add_argument("--version", action="version", version=f"bioscara {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        module = importlib.import_module(f".commands.{name}", __package__)
        uses = tuple(getattr(module, "USES", ALL_OPTIONS))
        command = sub.add_parser(module.NAME, parents=[_common(uses, top=False)], help=module.HELP,
                                 description=module.HELP)
        module.add_arguments(command)
        command.set_defaults(handler=module.run, uses=uses)
    return parser


def _safe_streams() -> None:
    """Text that came from undecodable bytes (arguments, file names) prints as escapes, never raises."""
    for stream in (sys.stdout, sys.stderr):
        reconfigure = getattr(stream, "reconfigure", None)
        if reconfigure is not None:
            try:
                reconfigure(errors="backslashreplace")
            except (ValueError, OSError):
                pass


def _quiet_stdout() -> None:
    """Point stdout at /dev/null, so the interpreter's last flush does not fail on the closed pipe."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)


def main(argv: list[str] | None = None, *, bus: Bus | None = None) -> int:
    """Run one command. `bus`: use this open bus instead of the config's (embedding, tests)."""
    _safe_streams()
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse has printed the usage error (or --help, --version)
        return exc.code if isinstance(exc.code, int) else USAGE
    level = (logging.WARNING, logging.INFO, logging.DEBUG)[min(args.verbose, 2)]
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    session = Session(args, bus)
    with interruption.stop_on_signals():
        return _run(args, session)


def _run(args: argparse.Namespace, session: Session) -> int:
    try:
        given = [option for option, default in TOP_DEFAULTS.items() if getattr(args, option) != default]
        unused = [f"--{option}" for option in given if option not in args.uses]
        if unused:
            raise InvalidArgumentError(f"`bioscara {args.command}` takes no {' or '.join(unused)}")
        return int(args.handler(args, session) or 0)
    except KeyboardInterrupt as exc:  # Ctrl-C, SIGTERM, SIGHUP: a joint this command moves stops here
        cause = exc.cause if isinstance(exc, interruption.Interrupted) else "Ctrl-C"
        session.err(f"interrupted ({cause})")
        interruption.stop_arms(session.arms, session.err)
        return interruption.exit_status(exc)
    except BrokenPipeError:  # the reader left (`| head`): nobody to tell, end quietly as `yes | head` does
        _quiet_stdout()
        return BROKEN_PIPE
    except (ConfigError, InvalidArgumentError) as exc:
        session.fail(exc, USAGE)
        return USAGE
    except (BioscaraError, OSError) as exc:
        session.fail(exc, DEVICE)
        return DEVICE
    except Exception as exc:  # a bug: still one line (the traceback with -vv)
        logging.getLogger("bioscara").debug("internal error", exc_info=True)
        session.err(f"internal error: {type(exc).__name__}: {exc} (please report it; -vv shows where)")
        return INTERNAL
    finally:
        session.close()


if __name__ == "__main__":
    sys.exit(main())
