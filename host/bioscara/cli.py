"""The `bioscara` command line: one module per command in `bioscara.commands`.

Every command accepts `--bus URL`, `--config FILE` and `--json`. Failures the user can act on
(bus errors, missing devices, bad arguments, broken config files) print one line and exit non-zero.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from .arm import PROTOCOLS
from .bus import Bus
from .commands import COMMANDS
from .errors import BioscaraError, ConfigError
from .session import Session


def build_parser() -> argparse.ArgumentParser:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--bus", metavar="URL", help="smbus:1, blinka:, serial:/dev/ttyACM0 or sim: "
                        "(default: the config's bus)")
    common.add_argument("--config", metavar="FILE", help="arm configuration (TOML; default: the shipped "
                        "J1-J4 configuration on the simulator)")
    common.add_argument("--json", action="store_true", help="machine-readable output")
    common.add_argument("--protocol", choices=PROTOCOLS, default="auto",
                        help="joint protocol: auto (v2 where the joint serves it), legacy or v2 "
                        "(default: auto)")
    common.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    parser = argparse.ArgumentParser(prog="bioscara", description="Bioscara SCARA arm tools")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        module = importlib.import_module(f".commands.{name}", __package__)
        command = sub.add_parser(module.NAME, parents=[common], help=module.HELP, description=module.HELP)
        module.add_arguments(command)
        command.set_defaults(handler=module.run)
    return parser


def main(argv: list[str] | None = None, *, bus: Bus | None = None) -> int:
    """Run one command. `bus`: use this open bus instead of the config's (embedding, tests)."""
    args = build_parser().parse_args(argv)
    level = (logging.WARNING, logging.INFO, logging.DEBUG)[min(args.verbose, 2)]
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    session = Session(args, bus)
    try:
        return int(args.handler(args, session) or 0)
    except KeyboardInterrupt:
        session.err("interrupted")
        return 130
    except ConfigError as exc:
        session.err(f"error: {exc.detail}")
        return 2
    except (BioscaraError, OSError) as exc:
        session.err(f"error: {exc}")
        return 1
    finally:
        session.close()


if __name__ == "__main__":
    sys.exit(main())
