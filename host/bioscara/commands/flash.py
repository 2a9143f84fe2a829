"""`bioscara flash PORT --joint J1`: deploy the joint firmware onto a MicroPython board."""

from __future__ import annotations

import argparse

from rich.progress import BarColumn, DownloadColumn, Progress, TextColumn
from rich.text import Text

from .. import flash, mpboard
from ..session import Session

NAME = "flash"
HELP = ("deploy the joint firmware onto a MicroPython board (mpremote): precompile, copy what changed, "
        "verify, reboot, and with --bus check the joint's version over the bus")
USES = ("bus", "json")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("port", help="the board's serial port, e.g. /dev/ttyACM0 or COM3")
    parser.add_argument("--joint", required=True, type=str.upper, choices=flash.JOINTS,
                        help="which joint the board drives: its configuration goes to /joint_config.json")
    parser.add_argument("--dry-run", action="store_true", help="show what would change; change nothing")
    parser.add_argument("--boot-timeout", type=float, default=10.0, metavar="S",
                        help="with --bus: how long the joint may take to answer after the reboot (s; default 10)")


def run(args: argparse.Namespace, session: Session) -> int:
    board = mpboard.open_board(args.port)
    try:
        plan = flash.plan(board, args.joint)
        if not args.dry_run:
            _apply(board, plan, session)
    finally:
        board.close()
    identity = None
    if args.bus and not args.dry_run:
        identity = flash.check_identity(session.bus, args.joint, plan.image.address, timeout=args.boot_timeout)
    session.emit(flash.report(plan, dry_run=args.dry_run, identity=identity),
                 human=_render(plan, args.dry_run, identity))
    if identity is not None and not identity.ok:
        raise flash.FlashError("version check failed: " + "; ".join(identity.problems))
    return 0


def _apply(board: mpboard.Board, plan: flash.Plan, session: Session) -> None:
    done: dict[str, int] = {}
    with Progress(TextColumn("{task.description}"), BarColumn(), DownloadColumn(),
                  console=session.console, transient=True, disable=not session.console.is_terminal) as bar:
        task = bar.add_task(f"flashing {plan.port}", total=plan.write_bytes)

        def advance(path: str, written: int) -> None:
            bar.update(task, advance=written - done.get(path, 0), description=path)
            done[path] = written

        flash.apply(board, plan, advance)


def _render(plan: flash.Plan, dry_run: bool, identity: flash.IdentityCheck | None) -> Text:
    out = Text()
    out.append(f"{plan.port}: {plan.board.describe()}\n")
    if plan.board.installed_firmware:
        out.append(f"installed: firmware {'.'.join(map(str, plan.board.installed_firmware))} "
                   f"for {plan.board.installed_joint or 'no joint'}\n")
    out.append(f"firmware {flash.FIRMWARE} for {plan.image.joint} "
               f"(I2C 0x{plan.image.address:02x}), {plan.image.build}\n",
               style=None if plan.image.compiled else "yellow")
    for warning in plan.warnings:
        out.append(f"warning: {warning}\n", style="yellow")
    if dry_run:
        out.append("dry run, nothing was changed; flashing would:\n")
    labels = ("add", "update", "remove") if dry_run else ("added", "updated", "removed")
    for label, paths, style in zip(labels, (plan.added, plan.updated, plan.stale), ("green", "cyan", "red")):
        for path in paths:
            out.append(f"  {label:<8} {path}\n", style=style)
    out.append(f"  {len(plan.unchanged)} file(s) unchanged")
    if dry_run:
        return out
    out.append("\nverified (SHA-256 of every file, import joint.app on the board); soft-reset\n")
    if identity is None:
        out.append("version check skipped (no --bus given)", style="yellow")
    elif identity.ok:
        found = identity.found or {}
        out.append(f"version check: 0x{identity.address:02x} runs firmware {found.get('firmware')} "
                   f"as joint {found.get('joint_id')}, same protocol spec", style="green")
    return out
