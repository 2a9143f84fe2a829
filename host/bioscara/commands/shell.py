"""`bioscara shell`: the interactive console (`bioscara.shell_interpreter`) behind a prompt_toolkit line editor.

Interactive on a terminal (history, tab completion, Ctrl-C cancels the line, Ctrl-D leaves);
non-interactive with `--script FILE` or when stdin is not a terminal, exiting 1 at the first
failing line. On the simulator the joints run in real time, so the communicator thread cycles at
wall-clock pace (in virtual time it would race ahead of the person typing).
"""

from __future__ import annotations

import argparse
import signal
import sys
from collections.abc import Iterable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from .. import interruption
from ..arm import Arm, Lifecycle
from ..bus import Bus
from ..config import ArmConfig
from ..paths import default_state_dir, private_file
from ..hardware import open_arm, open_arm_bus
from ..session import Session
from ..errors import InvalidArgumentError
from ..shell_interpreter import Shell, script_lines
from .options import count, positive

NAME = "shell"
HELP = "interactive console: communicator, arm lifecycle, command modes, registers (`help` inside)"
USES = ("bus", "protocol", "config", "take_over")

def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--script", metavar="FILE", help="run FILE's commands and exit; non-zero at the first "
                        "failing line ('-': stdin, also the default when stdin is not a terminal)")
    parser.add_argument("--keep-going", action="store_true",
                        help="with a script: run every line, exit non-zero if any failed")
    parser.add_argument("--expert", action="store_true",
                        help="allow `write`: raw register frames that bypass the arm's guards")
    parser.add_argument("--rate", type=positive("Hz"), default=100.0, metavar="HZ",
                        help="communicator frequency (default 100 Hz)")
    parser.add_argument("--priority", type=count(0, 99), default=50, metavar="N",
                        help="SCHED_FIFO priority of the communicator thread, 0 for normal scheduling (default 50)")
    parser.add_argument("--history", metavar="FILE", type=Path,
                        help="history file (default $XDG_STATE_HOME/bioscara/shell_history)")


@dataclass(frozen=True)
class Context:
    """The configuration, bus and arm the shell works on."""

    config: ArmConfig
    bus: Bus
    arm: Arm


def run(args: argparse.Namespace, session: Session) -> int:
    if args.script not in (None, "-"):
        script_lines(Path(args.script))  # refuses an unreadable script before the bus is opened
    context = open_context(session.config, session.protocol, take_over=bool(getattr(args, "take_over", False)))
    session.drives(context.arm)
    shell = Shell(context, out=lambda text: session.console.print(text, markup=False, highlight=False,
                                                                  soft_wrap=True),
                  err=session.err, expert=args.expert, frequency=args.rate, priority=args.priority or None,
                  keep_alive=True)
    try:
        if args.script not in (None, "-"):
            lines = script_lines(Path(args.script))
            return 0 if shell.run_lines(lines, args.script, keep_going=args.keep_going) else 1
        if args.script == "-" or not sys.stdin.isatty():
            stdin = getattr(sys.stdin, "buffer", None)
            lines = script_lines(stdin) if stdin is not None else sys.stdin
            return 0 if shell.run_lines(lines, "<stdin>", keep_going=args.keep_going) else 1
        session.console.print(f"bioscara shell on {context.bus.describe()}, joints {', '.join(context.arm.joints)}"
                              f"{' (expert: raw writes allowed)' if args.expert else ''}; `help` lists the "
                              "commands", highlight=False)
        return interactive(shell, args.history or default_state_dir() / "shell_history")
    finally:
        close_context(shell, context, session)


def open_context(config: ArmConfig, protocol: str = "auto", *, take_over: bool = False) -> Context:
    """Open the configured bus (the simulator in real time) and the arm (`--protocol`; `--take-over`
    from the program that commands it, if any)."""
    if config.bus_url.startswith("sim:"):
        config = replace(config, sim=replace(config.sim, realtime=True))
    bus = open_arm_bus(config)
    return Context(config, bus, open_arm(config, bus, protocol, take_over=take_over))


def close_context(shell: Shell, context: Context, session: Session) -> None:
    """Leave the arm as `move` does: STOP the active joints and say where they hold, stop the
    communicator, let go of the joints (a holding joint keeps holding; a vertical joint would
    drop if disabled), release the bus."""
    try:
        if context.arm.lifecycle is Lifecycle.ACTIVE:
            interruption.stop_arms([context.arm], lambda text: session.err(f"leaving the shell: {text}; "
                                                                            "the joints keep holding"))
        shell.close()
        context.arm.release()
    except Exception as exc:  # report, but still release the bus
        session.err(f"error: leaving the arm: {exc}")
    finally:
        context.bus.close()


def interactive(shell: Shell, history: Path, *, input: Any = None, output: Any = None) -> int:
    """Prompt for commands until `quit` or EOF. `input`/`output` are prompt_toolkit's (tests pass pipes)."""
    from prompt_toolkit import PromptSession
    from prompt_toolkit.history import FileHistory, History, InMemoryHistory
    from prompt_toolkit.patch_stdout import patch_stdout

    store: History
    try:
        store = FileHistory(str(private_file(history)))  # appends each accepted line to the file
    except OSError as exc:
        shell.err(f"history not saved: {exc}")
        store = InMemoryHistory()
    prompt: PromptSession[str] = PromptSession(history=store, completer=_completer(shell), input=input,
                                               output=output)
    with patch_stdout(raw=True):  # output from other threads stays off the line being edited; colours pass
        while not shell.done:
            try:
                line = prompt.prompt(shell.prompt)
            except KeyboardInterrupt:
                continue  # Ctrl-C discards the line being typed
            except EOFError:
                break
            try:
                shell.execute(line)
            except KeyboardInterrupt as exc:
                if isinstance(exc, interruption.Interrupted) and exc.signum != signal.SIGINT:
                    raise  # SIGTERM, a closed terminal: leave (the arm stops on the way out)
                shell.err("interrupted: stopping the arm")
                interruption.stop_arms([shell.arm], shell.err)
    return 0


def _completer(shell: Shell) -> Any:
    from prompt_toolkit.completion import CompleteEvent, Completer, Completion
    from prompt_toolkit.document import Document

    class ShellCompleter(Completer):
        def get_completions(self, document: Document, complete_event: CompleteEvent) -> Iterable[Completion]:
            text = document.text_before_cursor
            word = "" if not text or text[-1].isspace() else text.split()[-1]
            for candidate in shell.complete(text):
                yield Completion(candidate, start_position=-len(word))

    return ShellCompleter()
