"""The `bioscara` command line."""

from __future__ import annotations

import argparse
import logging
import sys


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="bioscara", description="Bioscara SCARA arm tools")
    commands = parser.add_subparsers(dest="command", required=True)
    commands.add_parser("demo", help="simulated pick and place (no hardware needed)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    if args.command == "demo":
        from . import demo
        demo.run()
    return 0


if __name__ == "__main__":
    sys.exit(main())
