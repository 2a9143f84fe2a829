"""The README is a test: its tour of the simulated arm runs, in order, on the shared simulated arm,
and every command prints what the README says (`…` stands for anything; tests/doc_blocks.py)."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import pytest

from bioscara import sim_service
from tests.doc_blocks import run_session, steps

README = Path(__file__).resolve().parent.parent / "README.md"
MAX_README_BYTES = 15 * 1024  # the README is the way in; the rest is the docs site


def session_block() -> list[tuple[str, list[str]]]:
    """The README's console block after 'A session on the simulated arm': (command, expected lines)."""
    text = README.read_text()
    start = text.index("**A session on the simulated arm.**")
    block = text[text.index("```console\n", start) + len("```console\n"):]
    return steps(block[:block.index("```")])


@pytest.fixture
def state_dir(private_home: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    monkeypatch.delenv("BIOSCARA_BUS")  # the README's default bus: the shared simulated arm
    path = private_home / "state" / "bioscara"
    yield path
    if path.exists():
        sim_service.stop(path)


def test_the_readme_session_runs_as_written(state_dir: Path, tmp_path: Path) -> None:
    session = session_block()
    commands = [command.split()[1] for command, _ in session if command != "wait"]
    assert commands[:4] == ["sim", "scan", "home", "move"]
    assert {"monitor", "plot", "panel"} <= set(commands)  # the tour the README promises
    run_session(session, tmp_path)
    samples = (tmp_path / "monitor.txt").read_text().splitlines()
    assert re.fullmatch(r"\d+ samples at \d+\.\d Hz, \d+ rows in run\.csv", samples[-1]), samples[-1]
    assert (tmp_path / "run.png").read_bytes()[:4] == b"\x89PNG"


def test_the_readme_is_short() -> None:
    assert len(README.read_bytes()) <= MAX_README_BYTES


def test_the_readme_links_to_pages_that_exist() -> None:
    links = re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", README.read_text())
    local = [link for link in links if "://" not in link]
    assert "docs/hardware.md" in local
    assert [link for link in local if not (README.parent / link).exists()] == []


def test_the_readme_names_no_stale_module() -> None:
    from docgen.hooks import stale_references
    assert stale_references(README.read_text()) == []
