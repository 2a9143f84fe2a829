"""The command reference, generated from the CLI's own argparse parser (bioscara.cli.build_parser)."""

from __future__ import annotations

import argparse
import importlib
from types import ModuleType

from bioscara import cli
from bioscara.commands import COMMANDS


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:  # argparse has no public way to list subcommands
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    raise LookupError("the bioscara parser has no subcommands")


def _option_row(action: argparse.Action) -> str:
    if action.option_strings:
        value = ""
        if action.nargs != 0:
            value = " " + (action.metavar or action.dest.upper() if not action.choices
                           else "{" + ",".join(map(str, action.choices)) + "}")
        name = ", ".join(f"`{option}{value}`" for option in action.option_strings)
    else:
        name = f"`{action.metavar or action.dest}`"
        if action.choices and not isinstance(action, argparse._SubParsersAction):
            name += f" (`{'`, `'.join(map(str, action.choices))}`)"
        if action.nargs in ("*", "?"):
            name += " (optional)"
        elif action.nargs == "+":
            name += " (one or more)"
    help_text = (action.help or "").replace("|", "\\|").replace("\n", " ")
    if action.default not in (None, argparse.SUPPRESS, False) and "default" not in help_text \
            and action.option_strings and action.nargs != 0:
        help_text += f" (default: {action.default})"
    return f"| {name} | {help_text} |"


def _usage(parser: argparse.ArgumentParser) -> str:
    usage = parser.format_usage().strip()
    return " ".join(usage.removeprefix("usage:").split())


def command_modules() -> list[ModuleType]:
    """The command modules, in the CLI's order."""
    return [importlib.import_module(f"bioscara.commands.{name}") for name in COMMANDS]


def markdown() -> str:
    """Every command, its options (from the parser) and its examples (the module's EXAMPLES)."""
    parser = cli.build_parser()
    commands = _subparsers(parser)
    out = ["| command | does |", "|---|---|"]
    out += [f"| [`{name}`](#{name}) | {(sub.description or '').replace('|', '/')} |" for name, sub in commands.items()]
    out += ["", "Options of `bioscara` itself:", "", "| option | meaning |", "|---|---|"]
    out += [_option_row(a) for a in parser._actions if a.option_strings and a.dest != "help"]
    common = cli._common(cli.ALL_OPTIONS, top=True)._actions
    common_names = {a.dest for a in common}
    out += ["", "<a id=\"common-options\"></a>The common options, taken by every command that uses them "
            "(listed with each command; `--json` and `-v` also go before the command):", "",
            "| option | meaning |", "|---|---|", *[_option_row(a) for a in common]]
    for module in command_modules():
        name, sub = module.NAME, commands[module.NAME]
        examples = getattr(module, "EXAMPLES", ())
        if not examples:
            raise ValueError(f"`bioscara {name}` has no EXAMPLES ({module.__file__})")
        out += ["", f"## `bioscara {name}` {{#{name}}}", "", sub.description or "", "", "```text",
                _usage(sub), "```", ""]
        rows = [_option_row(a) for a in sub._actions if a.dest != "help" and a.dest not in common_names]
        if rows:
            out += ["| argument | meaning |", "|---|---|", *rows, ""]
        shared = [f"`{a.option_strings[0]}`" for a in sub._actions if a.dest in common_names]
        out += [f"[Common options](#common-options): {', '.join(shared)}.", ""]
        out += ["Examples:", "", "```sh"]
        width = max(len(command) for command, _ in examples)
        out += [f"{command.ljust(width)}   # {what}" for command, what in examples]
        out += ["```"]
    return "\n".join(out) + "\n"
