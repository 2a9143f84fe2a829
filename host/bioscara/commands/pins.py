"""`bioscara pins [j1|FILE.json]`: the wiring of a joint board, from its joint configuration."""

from __future__ import annotations

import argparse
import re

from rich.table import Table

from .. import firmware_flash, wiring
from ..errors import InvalidArgumentError
from ..session import Session

NAME = "pins"
HELP = "the wiring and pin map of a joint board (Pico, TMC2209, AS5600), from its joint configuration"
USES = ("json",)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("joint", nargs="?", default="j1", metavar="JOINT|FILE.json",
                        help="a shipped joint (j1..j4, default j1) or a joint configuration you wrote")
    parser.add_argument("--markdown", action="store_true", help="print the table as Markdown")


def run(args: argparse.Namespace, session: Session) -> int:
    if args.joint.upper() in firmware_flash.JOINTS:
        _, cfg = firmware_flash.joint_config(args.joint.upper())
    elif re.fullmatch(r"[jJ]\d+", args.joint):
        raise InvalidArgumentError(f"no joint {args.joint}; the joints are "
                                   f"{', '.join(j.lower() for j in firmware_flash.JOINTS)} (or a FILE.json you wrote)")
    else:
        _, cfg = firmware_flash.user_joint_config(args.joint)
    rows = wiring.pin_map(cfg)
    if args.markdown and session.json:
        raise InvalidArgumentError("--markdown or --json: one output at a time")
    if args.markdown:
        print(wiring.markdown(cfg), end="")
        return 0
    table = Table("Pico pin", "signal", "connects to", title=f"{cfg.joint.lower()} board ({cfg.source})")
    for row in rows:
        table.add_row(*row)
    session.emit({"joint": cfg.joint.lower(), "address": cfg.address,
                  "pins": [{"pin": p, "signal": s, "connects_to": t} for p, s, t in rows]}, table)
    return 0
