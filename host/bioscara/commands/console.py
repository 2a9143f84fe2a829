"""`bioscara console PORT`: a joint's serial debug console (a real joint, or a simulated joint's
pseudo-terminal from `bioscara sim`).

Interactive on a terminal: the joint's log lines scroll above a prompt with history and completion.
Lines are sent to the joint (`help` lists its commands); lines starting with ':' are the
console's own: `:capture FILE.csv`, `:capture off`, `:plot [COLUMN...]` (a live chart until
Ctrl-C), `:quit`. Non-interactive with `--command` or when stdin is not a terminal: the commands
are sent, the output is printed for `--duration` seconds, then it exits.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from pathlib import Path
from typing import Any

from ..serial_console import PLOT_COLUMNS, JointConsole, plot
from ..errors import BioscaraError, CommError, InvalidArgumentError
from ..firmware.console.debug_commands import TRACE_COLUMNS
from ..paths import default_state_dir, private_file
from ..serial_port import DEFAULT_BAUD
from ..session import Session
from .options import count, non_negative

NAME = "console"
HELP = "a joint's serial debug console: log lines, status, trace capture to CSV, live trace plot"
USES = ()  # a serial port, not the bus; interactive text, not JSON

JOINT_COMMANDS = ("status", "regs", "trace on", "trace off", "log ERROR", "log WARN", "log INFO",
                  "log DEBUG", "help")
LOCAL_HELP = (
    ":capture FILE.csv   capture the trace to a CSV file (turns the trace on)",
    ":capture off        end the capture",
    ":plot [COLUMN...]   live chart of the trace until Ctrl-C; columns: " + " ".join(TRACE_COLUMNS),
    ":quit               leave (also Ctrl-D)",
)
PLOT_WINDOW_S = 5.0
FIRST_ANSWER_S = 1.0  # a joint answers a command within milliseconds; the HIL bridge never does
OK, ERROR, QUIT = "ok", "error", "quit"  # outcomes of a line; a plot request is its columns (a tuple)
Outcome = str | tuple[str, ...]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("port", help="serial port of the joint (/dev/ttyACM0) or a path from `bioscara sim`")
    parser.add_argument("--baud", type=count(50, 10_000_000), default=DEFAULT_BAUD, help="only matters on a real UART")
    parser.add_argument("-c", "--command", action="append", default=[], metavar="LINE",
                        help="send LINE (repeatable; ':' lines are console commands), print the output for "
                        "--duration seconds, exit")
    parser.add_argument("--duration", type=non_negative("s"), default=1.0, metavar="S",
                        help="non-interactive: how long to keep printing after the last command (default 1)")
    parser.add_argument("--capture", metavar="FILE.csv", help="capture the trace to a CSV file")
    parser.add_argument("--plot", nargs="*", metavar="COLUMN",
                        help="chart the trace (default columns: " + " ".join(PLOT_COLUMNS) + "): live "
                        "when interactive, once at the end otherwise")
    parser.add_argument("--history", metavar="FILE", help="command history file (default: in the state directory)")


def run(args: argparse.Namespace, session: Session) -> int:
    if not args.duration >= 0:
        raise InvalidArgumentError(f"--duration must be >= 0 s, got {args.duration}")
    columns = tuple(args.plot or PLOT_COLUMNS) if args.plot is not None else None
    if columns is not None:
        try:
            plot([], columns)  # rejects unknown columns before the port is opened
        except ValueError as exc:
            raise InvalidArgumentError(str(exc)) from None
    out = Printer()
    console = JointConsole(args.port, baud=args.baud, on_line=out)
    try:
        if args.capture:
            console.start_capture(args.capture)
        if args.command or not sys.stdin.isatty():
            lines = args.command or [line.rstrip("\n") for line in sys.stdin]
            return batch(console, lines, args.duration, out, columns)
        out(f"console: {args.port}; `help` lists the joint's commands, `:help` the console's")
        history = Path(args.history) if args.history else default_state_dir() / "console_history"
        return interactive(console, history, out, columns)
    finally:
        capture = console.stop_capture()
        console.close()
        if capture is not None:
            out(f"console: {capture.rows} trace samples written to {capture.path}")


class Printer:
    """Prints whole lines from any thread, flushed (the output may be a pipe); counts the joint's
    errors: its console's `error: ...` answers and its ERROR log lines."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.joint_errors = 0
        self.reader_gone = False  # stdout is a pipe whose reader left (`| head`)

    def __call__(self, line: str) -> None:
        words = line.split(maxsplit=2)
        with self._lock:
            if line.startswith("error:") or len(words) > 1 and words[1] == "ERROR":
                self.joint_errors += 1
            if self.reader_gone:
                return
            try:
                print(line, flush=True)
            except BrokenPipeError:  # in the reader thread: the command ends when the main thread looks
                self.reader_gone = True


def batch(console: JointConsole, lines: list[str], duration: float, out: Printer,
          columns: tuple[str, ...] | None) -> int:
    """Send `lines`, keep printing for `duration` s; exit status 1 if a console command failed."""
    status = 0
    for line in lines:
        outcome = local_or_send(console, line, out)
        if outcome == QUIT:
            break
        if outcome == ERROR:
            status = 1
        elif isinstance(outcome, tuple):
            columns = outcome
    # The joint answers and logs meanwhile (the reader thread prints); a port that has said nothing
    # yet gets FIRST_ANSWER_S, so a short --duration still tells a silent port from a joint.
    start = time.monotonic()

    def waiting() -> bool:
        now = time.monotonic()
        return now < start + duration or bool(lines) and not console.lines_received and now < start + FIRST_ANSWER_S
    while not out.reader_gone and waiting():
        time.sleep(0.02)
    if out.reader_gone:
        raise BrokenPipeError
    if lines and not console.lines_received:
        raise CommError(f"nothing answered on {console.path}: it is not a joint's debug console (a HIL bridge "
                        f"is used with --bus serial:{console.path}); `bioscara ports {console.path}` says what it is")
    if out.joint_errors:
        status = 1
    if columns is not None:
        from rich.console import Console
        Console(soft_wrap=True).print(plot(console.samples(PLOT_WINDOW_S), columns))
    return status


def local_or_send(console: JointConsole, line: str, out: Printer) -> Outcome:
    """Run a ':' line or send the line to the joint."""
    words = line.split()
    if not words:
        return OK
    if not words[0].startswith(":"):
        console.send(line.strip())
        if words == ["trace", "on"]:
            out("console: trace samples are not printed; `:plot` charts them, `:capture FILE.csv` saves them")
        return OK
    name, rest = words[0][1:], words[1:]
    if name in ("quit", "q", "exit"):
        return QUIT
    if name == "help":
        for text in LOCAL_HELP:
            out(text)
        return OK
    if name == "capture" and rest == ["off"]:
        capture = console.stop_capture()
        out(f"console: {capture.rows} samples in {capture.path}" if capture else "console: no capture runs")
        return OK
    if name == "capture" and len(rest) == 1:
        try:
            capture = console.start_capture(rest[0])
        except OSError as exc:
            out(f"console: cannot write {rest[0]}: {exc.strerror or exc}")
            return ERROR
        out(f"console: capturing the trace to {capture.path}")
        return OK
    if name == "plot":
        columns = tuple(rest) or PLOT_COLUMNS
        try:
            plot([], columns)
        except ValueError as exc:
            out(f"console: {exc}")
            return ERROR
        return columns
    out(f"console: unknown console command {words[0]!r}; `:help` lists them")
    return ERROR


def interactive(console: JointConsole, history: Path, out: Printer, columns: tuple[str, ...] | None) -> int:
    from prompt_toolkit import PromptSession
    from prompt_toolkit.completion import WordCompleter
    from prompt_toolkit.history import FileHistory, History, InMemoryHistory
    from prompt_toolkit.patch_stdout import patch_stdout

    store: History
    try:
        store = FileHistory(str(private_file(history)))
    except OSError:
        store = InMemoryHistory()
    words = JOINT_COMMANDS + tuple(text.split()[0] for text in LOCAL_HELP) + (":capture off",)
    prompt: PromptSession[str] = PromptSession(history=store, completer=WordCompleter(list(words), sentence=True))
    while True:
        if columns is not None:
            live_plot(console, columns)
        with patch_stdout():  # log lines from the reader thread scroll above the line being typed
            outcome = _prompt(prompt, console, out)
        if outcome == QUIT:
            return 0
        columns = outcome if isinstance(outcome, tuple) else None


def _prompt(prompt: Any, console: JointConsole, out: Printer) -> Outcome:
    """Read and run lines until one asks to quit or to plot."""
    while True:
        try:
            line = prompt.prompt(f"{console.path}> ")
        except KeyboardInterrupt:
            continue  # Ctrl-C discards the line being typed
        except EOFError:
            return QUIT
        try:
            outcome = local_or_send(console, line, out)
        except BioscaraError as exc:  # e.g. the port is gone for now: keep the session
            out(f"console: {exc.detail}")
            continue
        if outcome == QUIT or isinstance(outcome, tuple):
            return outcome


def live_plot(console: JointConsole, columns: tuple[str, ...]) -> None:
    """Redraw the chart of the last PLOT_WINDOW_S seconds ten times a second until Ctrl-C."""
    from rich.console import Console
    from rich.live import Live

    terminal = Console()

    def chart() -> Any:
        width, height = terminal.size
        return plot(console.samples(PLOT_WINDOW_S), columns, width=width, height=max(height - 4, 6),
                    title=f"{console.path}: last {PLOT_WINDOW_S:g} s, Ctrl-C returns to the prompt")

    with Live(chart(), console=terminal, refresh_per_second=10, transient=True) as live:
        try:
            while True:
                time.sleep(0.1)
                live.update(chart())
        except KeyboardInterrupt:
            pass
