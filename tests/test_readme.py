"""The README is a test: its session on the simulated arm runs, in order, on the shared simulated arm,
and every command prints what the README says (`…` stands for anything)."""

from __future__ import annotations

import os
import re
import shlex
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from bioscara import sim_service

README = Path(__file__).resolve().parent.parent / "README.md"
COMMAND_TIMEOUT_S = 60.0


def session_block() -> list[tuple[str, list[str]]]:
    """The README's console block after 'A session on the simulated arm': (command, expected lines)."""
    text = README.read_text()
    start = text.index("**A session on the simulated arm.**")
    block = text[text.index("```console\n", start) + len("```console\n"):]
    block = block[:block.index("```")]
    steps: list[tuple[str, list[str]]] = []
    for line in block.splitlines():
        if line.startswith("$ "):
            steps.append((line[2:], []))
        elif line:
            steps[-1][1].append(line)
    return steps


BOX = str.maketrans("", "", "│┃┏┓┗┛━─┡┩╇┳┻╋┼┌┐└┘├┤")  # the README shows a terminal; piped, tables have no box


def pattern(expected: str) -> re.Pattern[str]:
    """`…` matches anything (with the spaces around it); a space matches any run of spaces (table padding)."""
    parts = [re.escape(part.strip()).replace("\\ ", r"\s+") for part in expected.translate(BOX).split("…")]
    return re.compile(r"\s*.*?\s*".join(parts))


@pytest.fixture
def state_dir(private_home: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    monkeypatch.delenv("BIOSCARA_BUS")  # the README's default bus: the shared simulated arm
    path = private_home / "state" / "bioscara"
    yield path
    if path.exists():
        sim_service.stop(path)


def test_the_readme_session_runs_as_written(state_dir: Path, tmp_path: Path) -> None:
    steps = session_block()
    assert [command.split()[1] for command, _ in steps if command != "wait"][:4] == ["sim", "scan", "home", "move"]
    bioscara = f"{shlex.quote(sys.executable)} -m bioscara.cli"
    background: list[subprocess.Popen[str]] = []
    try:
        for command, expected in steps:
            if command == "wait":
                for process in background:
                    assert process.wait(timeout=COMMAND_TIMEOUT_S) == 0, process.args
                continue
            shell_command = command.replace("bioscara ", f"{bioscara} ", 1)
            if shell_command.endswith(" &"):
                background.append(subprocess.Popen(shell_command[:-2], shell=True, cwd=tmp_path, text=True,
                                                   env=os.environ, start_new_session=True))
                continue
            result = subprocess.run(shell_command, shell=True, cwd=tmp_path, capture_output=True, text=True,
                                    timeout=COMMAND_TIMEOUT_S, env=os.environ)
            output = (result.stdout + result.stderr).splitlines()
            failing = bool(expected) and expected[0].startswith("error: ")
            assert (result.returncode != 0) == failing, (command, result.returncode, result.stderr)
            lines = iter(output)
            for want in expected:
                assert any(pattern(want).fullmatch(line.strip()) for line in lines), (command, want, output)
            assert "Traceback" not in result.stderr, (command, result.stderr)
    finally:  # a failed step leaves no command running (the service itself: the fixture)
        for process in background:
            if process.poll() is None:
                os.killpg(process.pid, signal.SIGKILL)  # the shell and the command it runs
                process.wait()
    samples = (tmp_path / "monitor.txt").read_text().splitlines()
    assert re.fullmatch(r"\d+ samples at \d+\.\d Hz, \d+ rows in run\.csv", samples[-1]), samples[-1]
    assert (tmp_path / "run.png").read_bytes()[:4] == b"\x89PNG"
