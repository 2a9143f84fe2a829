"""`bioscara flash PORT --joint j1`: deploy the joint firmware onto a MicroPython board;
`bioscara flash --joint j1 --dry-run`: what it would deploy, without a board."""

from __future__ import annotations

import argparse
import json

from rich.progress import BarColumn, DownloadColumn, Progress, TextColumn
from rich.text import Text

from .. import firmware_flash, mpboard, s32flash
from ..errors import InvalidArgumentError
from ..session import Session
from .options import shown

NAME = "flash"
HELP = ("deploy the joint firmware onto a MicroPython board (mpremote): precompile, copy what changed, "
        "verify, reboot, and with --bus check the joint's version over the bus")
USES = ("bus", "json")  # --bus for the version check, which needs no --protocol


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("port", nargs="?", help="the board's serial port, e.g. /dev/ttyACM0 or COM3 "
                        "(`bioscara ports` lists them); not needed with --dry-run")
    parser.add_argument("--joint", type=_joint, metavar="JOINT",
                        help="j1..j4: which joint the board drives; the shipped configuration of that joint "
                        "goes to /joint_config.json (not needed with --joint-config)")
    parser.add_argument("--joint-config", metavar="FILE.json",
                        help="deploy this joint configuration instead (your pins, driver address, sense "
                        "resistor...): validated as the firmware will, before the board is touched")
    parser.add_argument("--show-config", action="store_true",
                        help="only show the board's current /joint_config.json (and whether it is valid)")
    parser.add_argument("--board", choices=firmware_flash.boards(), default=firmware_flash.DEFAULT_BOARD,
                        help="which board's manifest to deploy (firmware/joint/boards/BOARD.py; default: %(default)s); "
                        "s32: a uStepper S32 in its ROM DFU bootloader (BOOT0), written with dfu-util: the image "
                        "from `make s32-image` and the joint's configuration (docs/s32.md)")
    parser.add_argument("--dry-run", action="store_true",
                        help="show what would change on the board, changing nothing; without PORT: the files "
                        "(and sizes) that would go onto a stock Raspberry Pi Pico, the joint config validated")
    parser.add_argument("--debug", action="store_true",
                        help="keep the source line numbers in the precompiled files, so that a traceback on the "
                        "board names the line (costs about 0.7 KB of the board's heap)")
    parser.add_argument("--image", metavar="FIRMWARE.bin", default=str(s32flash.DEFAULT_IMAGE),
                        help=f"with --board s32: the image to write (default {s32flash.DEFAULT_IMAGE})")
    parser.add_argument("--boot-timeout", type=float, default=10.0, metavar="S",
                        help="with --bus: how long the joint may take to answer after the reboot (s; default 10)")


def _joint(text: str) -> str:
    """j1 or J1 -> "J1", the firmware's name (printed j1)."""
    name = text.strip().upper()
    if name not in firmware_flash.JOINTS:
        raise argparse.ArgumentTypeError(f"no joint {shown(text)}; the joints are j1, j2, j3, j4")
    return name


def run(args: argparse.Namespace, session: Session) -> int:
    if args.board == "s32":
        return _run_s32(args, session)
    if args.show_config:
        if args.port is None:
            raise InvalidArgumentError("--show-config reads a board: give its serial port (`bioscara ports` lists them)")
        return _show_config(args, session)
    if args.port is None and not args.dry_run:
        raise InvalidArgumentError("which board? give its serial port (`bioscara ports` lists them), "
                                   "or --dry-run to see what would be deployed")
    if args.dry_run and args.bus:
        raise InvalidArgumentError("--bus checks the flashed joint's version: a dry run flashes nothing to check")
    config = firmware_flash.user_joint_config(args.joint_config) if args.joint_config else None
    joint = config[1].joint if config is not None else args.joint
    if joint is None:
        raise InvalidArgumentError("which joint? give --joint j1..j4, or --joint-config FILE.json")
    if args.joint and config is not None and args.joint != joint:
        raise InvalidArgumentError(f"{args.joint_config} configures {joint.lower()}, not {args.joint.lower()}")
    if args.port is None:
        plan = firmware_flash.plan_without_board(joint, config, line_numbers=args.debug, manifest=args.board)
    else:
        board = mpboard.open_board(args.port)
        try:
            plan = firmware_flash.plan(board, joint, config, line_numbers=args.debug, manifest=args.board)
            if not args.dry_run:
                _apply(board, plan, session)
        finally:
            board.close()
    identity = None
    if args.bus and not args.dry_run:
        identity = firmware_flash.check_identity(session.bus, joint, plan.image.address, timeout=args.boot_timeout)
    source = args.joint_config or f"the shipped {joint.lower()} configuration"
    session.emit(firmware_flash.report(plan, dry_run=args.dry_run, identity=identity, config_source=source),
                 human=_render(plan, args.dry_run, identity, source))
    if identity is not None and not identity.ok:
        raise firmware_flash.FlashError("version check failed: " + "; ".join(identity.problems))
    return 0


def _run_s32(args: argparse.Namespace, session: Session) -> int:
    """The image and the joint's configuration onto a uStepper S32 in DFU mode."""
    from pathlib import Path

    if args.port is not None:
        raise InvalidArgumentError("an S32 is found by dfu-util on USB (BOOT0 held high at reset): give no PORT")
    if args.show_config:
        raise InvalidArgumentError("--show-config reads a MicroPython board's file; an S32 keeps its configuration "
                                   "in flash (flash it again to change it)")
    if args.dry_run and args.bus:
        raise InvalidArgumentError("--bus checks the flashed joint's version: a dry run flashes nothing to check")
    config = firmware_flash.user_joint_config(args.joint_config, "s32") if args.joint_config else None
    joint = config[1].joint if config is not None else args.joint
    if joint is None:
        raise InvalidArgumentError("which joint? give --joint j1..j4, or --joint-config FILE.json")
    if args.joint and config is not None and args.joint != joint:
        raise InvalidArgumentError(f"{args.joint_config} configures {joint.lower()}, not {args.joint.lower()}")
    image = s32flash.build(joint, Path(args.image), config)
    if not args.dry_run:
        s32flash.write(image)
    identity = None
    if args.bus and not args.dry_run:
        identity = firmware_flash.check_identity(session.bus, joint, image.address, timeout=args.boot_timeout)
    data = {"board": "s32", "joint": joint.lower(), "address": image.address, "image": str(image.firmware),
            "image_bytes": image.firmware_bytes, "config_address": f"0x{s32flash.CONFIG_ADDRESS:08x}",
            "config": json.loads(image.config), "dry_run": args.dry_run, "verified": not args.dry_run,
            "identity": None if identity is None else {"ok": identity.ok, "found": identity.found,
                                                       "problems": list(identity.problems)}}
    text = Text(f"uStepper S32, {joint.lower()} (I2C 0x{image.address:02x}): {image.firmware} "
                f"({image.firmware_bytes:,} of {s32flash.IMAGE_LIMIT:,} bytes), configuration "
                f"({len(image.config)} bytes) at 0x{s32flash.CONFIG_ADDRESS:08x}\n")
    if args.dry_run:
        text.append("dry run: nothing was written; dfu-util would write the image and the configuration, "
                    "read the configuration back and start the firmware")
    else:
        text.append("written with dfu-util; the configuration read back matches; the firmware started\n", style="green")
        if identity is None:
            text.append("identity check skipped (no --bus given)", style="yellow")
        elif identity.ok:
            text.append(f"identity: 0x{identity.address:02x} answers as {joint.lower()}, same firmware and protocol",
                        style="green")
    session.emit(data, text)
    if identity is not None and not identity.ok:
        raise firmware_flash.FlashError("identity check failed: " + "; ".join(identity.problems))
    return 0


def _show_config(args: argparse.Namespace, session: Session) -> int:
    """The board's /joint_config.json, checked as its firmware checks it at boot."""
    from ..firmware.config import schema as firmware_config

    board = mpboard.open_board(args.port)
    try:
        raw = board.read(firmware_flash.CONFIG_PATH)
    finally:
        board.close()
    if raw is None:
        session.emit({"port": args.port, "config": None, "valid": False, "problems": ["no /joint_config.json"]},
                     f"{args.port}: no {firmware_flash.CONFIG_PATH} (the joint boots disabled; flash one with --joint)")
        return 1
    try:
        data = json.loads(raw.decode("utf-8"))
        cfg = firmware_config.parse(data, firmware_flash.CONFIG_PATH)
        problems = list(cfg.errors)
    except (ValueError, RecursionError) as exc:
        data, problems = None, [f"not valid JSON ({str(exc)[:80]})"]
    text = Text(f"{args.port}: {firmware_flash.CONFIG_PATH}\n")
    text.append(json.dumps(data, indent=2) if data is not None else raw.decode("utf-8", "replace")[:2000])
    text.append("\n" + ("valid" if not problems else "INVALID: " + "; ".join(problems)),
                style="green" if not problems else "red")
    session.emit({"port": args.port, "config": data, "valid": not problems, "problems": problems}, text)
    return 0 if not problems else 1


def _apply(board: mpboard.Board, plan: firmware_flash.Plan, session: Session) -> None:
    done: dict[str, int] = {}
    with Progress(TextColumn("{task.description}"), BarColumn(), DownloadColumn(),
                  console=session.console, transient=True, disable=not session.console.is_terminal) as bar:
        task = bar.add_task(f"flashing {plan.port}", total=plan.write_bytes)

        def advance(path: str, written: int) -> None:
            bar.update(task, advance=written - done.get(path, 0), description=path)
            done[path] = written

        firmware_flash.apply(board, plan, advance)


def _render(plan: firmware_flash.Plan, dry_run: bool, identity: firmware_flash.IdentityCheck | None, source: str) -> Text:
    out = Text()
    if plan.assumed:
        out.append(f"no board given: what flashing would deploy on a stock Pico, {plan.board.describe()}; "
                   "give PORT to compare with a board's files\n")
    else:
        out.append(f"{plan.port}: {plan.board.describe()}\n")
    if plan.board.installed_firmware:
        installed = plan.board.installed_joint.lower() if plan.board.installed_joint else "no joint"
        out.append(f"installed: firmware {'.'.join(map(str, plan.board.installed_firmware))} for {installed}\n")
    out.append(f"firmware {firmware_flash.FIRMWARE} for {plan.image.joint.lower()} "
               f"(I2C 0x{plan.image.address:02x}), {plan.image.build}\n",
               style=None if plan.image.compiled else "yellow")
    out.append(f"joint config {firmware_flash.CONFIG_PATH}: {source}, valid (checked as the firmware checks it at boot)\n")
    for warning in plan.warnings:
        out.append(f"warning: {warning}\n", style="yellow")
    if dry_run:
        out.append("dry run, nothing was changed; flashing would:\n")
    labels = ("add", "update", "remove") if dry_run else ("added", "updated", "removed")
    files = plan.image.files
    for label, paths, style in zip(labels, (plan.added, plan.updated, plan.stale), ("green", "cyan", "red")):
        for path in paths:
            size = f"{len(files[path]):>7,} B" if path in files else ""
            out.append(f"  {label:<8} {path:<28} {size}\n", style=style)
    out.append(f"  {len(plan.unchanged)} file(s) unchanged; {plan.write_bytes:,} bytes to write")
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
