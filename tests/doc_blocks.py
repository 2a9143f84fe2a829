"""The documentation's code blocks as tests: a console session runs command by command, checking
each command's output; a Python block runs as a program. Shared by test_readme.py and test_docs.py.

A block is meant to run when the line before its fence is `<!-- runs: python -->` or
`<!-- runs: console -->`; a Python or console block that is not meant to run says why with
`<!-- not run: REASON -->` (test_docs.py checks that every one says one or the other).
"""

from __future__ import annotations

import os
import pty
import re
import select
import shlex
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

COMMAND_TIMEOUT_S = 60.0
MARKER = re.compile(r"^<!-- (runs|not run): ?([^>]*?) ?-->\n```(\w+)\n(.*?)^```", re.M | re.S)
FENCE = re.compile(r"^```(python|console)\n", re.M)
INTERACTIVE = ("bioscara panel",)  # full-screen commands: run in a pseudo-terminal, left with Ctrl-Q
CTRL_Q = b"\x11"
_ESCAPES = re.compile(rb"\x1b\[[0-9;?]*[ -/]*[@-~]|\x1b[()][A-Z0-9]|\x1b[=>]")


@dataclass(frozen=True)
class Block:
    source: str
    line: int
    run: bool
    note: str  # the kind to run (python, console) or the reason it does not run
    language: str
    text: str


def blocks(path: Path) -> list[Block]:
    """The marked blocks of a Markdown file."""
    text = path.read_text()
    return [Block(path.name, text.count("\n", 0, m.start()) + 1, m.group(1) == "runs", m.group(2), m.group(3),
                  m.group(4)) for m in MARKER.finditer(text)]


def unmarked(path: Path) -> list[int]:
    """Lines of the Python and console fences that carry no marker."""
    text = path.read_text()
    marked = {m.start(3) - 3 for m in MARKER.finditer(text)}
    return [text.count("\n", 0, m.start()) + 1 for m in FENCE.finditer(text) if m.start() not in marked]


def steps(block: str) -> list[tuple[str, list[str]]]:
    """A console block as (command, expected lines)."""
    result: list[tuple[str, list[str]]] = []
    for line in block.splitlines():
        if line.startswith("$ "):
            result.append((line[2:], []))
        elif line:
            result[-1][1].append(line)
    return result


BOX = str.maketrans("", "", "│┃┏┓┗┛━─┡┩╇┳┻╋┼┌┐└┘├┤")  # the docs show a terminal; piped, tables have no box


def pattern(expected: str) -> re.Pattern[str]:
    """`…` matches anything (with the spaces around it); a space matches any run of spaces (table
    padding); box-drawing characters are left out (a table the docs show boxed is plain when piped)."""
    parts = [re.escape(part.strip()).replace("\\ ", r"\s+") for part in expected.translate(BOX).split("…")]
    return re.compile(r"\s*.*?\s*".join(parts))


def _interactive(command: str, expected: list[str], cwd: Path) -> None:
    """A full-screen command in a 160x50 pseudo-terminal: wait until every expected text is on its
    screen, press Ctrl-Q, and expect it to end with status 0."""
    pid, fd = pty.fork()
    if pid == 0:
        os.chdir(cwd)
        os.environ.update(COLUMNS="160", LINES="50", TERM="xterm-256color")
        os.execvp("/bin/sh", ["/bin/sh", "-c", command])
    screen = b""
    try:
        deadline = time.monotonic() + COMMAND_TIMEOUT_S
        while not all(want.encode() in _ESCAPES.sub(b"", screen) for want in expected):
            assert time.monotonic() < deadline, (command, expected, _ESCAPES.sub(b"", screen)[-2000:])
            if select.select([fd], [], [], 0.1)[0]:
                screen += os.read(fd, 65536)
        os.write(fd, CTRL_Q)
        while True:
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                assert os.waitstatus_to_exitcode(status) == 0, (command, status)
                pid = 0
                return
            assert time.monotonic() < deadline, (command, "did not end after Ctrl-Q")
            if select.select([fd], [], [], 0.1)[0]:
                try:
                    os.read(fd, 65536)
                except OSError:
                    pass
    finally:
        if pid:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
        os.close(fd)


def run_session(session: list[tuple[str, list[str]]], cwd: Path) -> None:
    """Run a console session as written: `bioscara` is this interpreter's, a line ending in ` &`
    runs in the background until `wait`, and every command prints its expected lines in order
    (an expected `error: ...` means the command fails)."""
    bioscara = f"{shlex.quote(sys.executable)} -m bioscara.cli"
    background: list[subprocess.Popen[str]] = []
    try:
        for command, expected in session:
            if command == "wait":
                for process in background:
                    assert process.wait(timeout=COMMAND_TIMEOUT_S) == 0, process.args
                continue
            shell_command = command.replace("bioscara ", f"{bioscara} ", 1)
            if command.startswith(INTERACTIVE):
                _interactive(shell_command, expected, cwd)
                continue
            if shell_command.endswith(" &"):
                background.append(subprocess.Popen(shell_command[:-2], shell=True, cwd=cwd, text=True,
                                                   env=os.environ, start_new_session=True))
                continue
            result = subprocess.run(shell_command, shell=True, cwd=cwd, capture_output=True, text=True,
                                    timeout=COMMAND_TIMEOUT_S, env=os.environ)
            output = (result.stdout + result.stderr).splitlines()
            failing = bool(expected) and expected[0].startswith("error: ")
            assert (result.returncode != 0) == failing, (command, result.returncode, result.stderr)
            lines = iter(output)
            for want in expected:
                assert any(pattern(want).fullmatch(line.strip()) for line in lines), (command, want, output)
            assert "Traceback" not in result.stderr, (command, result.stderr)
    finally:  # a failed step leaves no command running
        for process in background:
            if process.poll() is None:
                os.killpg(process.pid, signal.SIGKILL)  # the shell and the command it runs
                process.wait()
