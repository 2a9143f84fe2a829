"""The documentation site: `make docs` builds it offline in strict mode without a warning, its
generated pages hold what the code holds, and every code block meant to run runs
(tests/doc_blocks.py; the README's tour is tests/test_readme.py's)."""

from __future__ import annotations

import os
import shlex
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace

import pytest

from bioscara import cli, errors
from bioscara.firmware.spec import protocol as P
from bioscara.firmware.spec import protocol_v2 as V
from docgen import cli_reference
from tests.doc_blocks import COMMAND_TIMEOUT_S, Block, blocks, run_session, steps, unmarked

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
KINDS = {"python", "console", "tour"}  # tour: the README's, run by test_readme.py


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """The site as `make docs` builds it (strict), into a temporary directory."""
    out = tmp_path_factory.mktemp("site")
    result = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
                            cwd=ROOT, capture_output=True, text=True, timeout=300,
                            env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert result.returncode == 0, result.stderr
    assert "WARNING" not in result.stderr, result.stderr
    yield out


def test_the_site_builds_strict_without_a_warning(site: Path) -> None:
    pages = {path.name for path in site.glob("*.html")}
    assert {"index.html", "commands.html", "api.html", "protocol.html", "troubleshooting.html", "safety.html",
            "internals.html", "benchmarks.html", "hardware.html", "simulator.html"} <= pages


def test_every_command_is_in_the_reference_with_an_example(site: Path) -> None:
    page = (site / "commands.html").read_text()
    commands = cli_reference._subparsers(cli.build_parser())
    assert len(commands) >= 17
    for name, parser in commands.items():
        assert f'id="{name}"' in page, name
        assert f"bioscara {name}" in page, name
        for action in parser._actions:  # every option of every command
            for option in action.option_strings:
                assert option in page, (name, option)


def test_the_protocol_page_holds_the_spec(site: Path) -> None:
    page = (site / "protocol.html").read_text()
    for register in P.REGISTERS:
        assert register.name in page, register.name
        assert f"0x{register.addr:02X}" in page, register.name
    for _, text in V.REASONS:
        assert text in page, text
    assert f"{P.SPEC_HASH:08x}" in page


def test_the_troubleshooting_page_holds_every_reason(site: Path) -> None:
    page = (site / "troubleshooting.html").read_text()
    for _, text in P.REJECT_REASONS:
        assert text.replace("'", "&#39;") in page or text in page, text
    for value, name, _ in P.ERROR_CODES:
        assert value == P.OK or name in page, name  # each exception's code
    for cls in (errors.BioscaraError, *errors.BioscaraError.__subclasses__()):
        assert cls.__name__ in page, cls.__name__


def test_the_pictures_are_drawn(site: Path) -> None:
    assert (site / "img" / "homing.png").read_bytes()[:4] == b"\x89PNG"
    for name in ("architecture", "protocol-legacy", "protocol-v2"):
        assert b"<svg" in (site / "img" / f"{name}.svg").read_bytes()[:2000], name
    assert "img/homing.png" in (site / "getting-started.html").read_text()


def test_every_python_and_console_block_says_whether_it_runs() -> None:
    for page in PAGES:
        assert unmarked(page) == [], f"{page.name}: blocks without <!-- runs: ... --> or <!-- not run: ... -->"
        for block in blocks(page):
            assert not block.run or block.note in KINDS, (page.name, block.line, block.note)
            assert block.run or block.note, (page.name, block.line, "say why it does not run")


RUNNABLE = [block for page in PAGES for block in blocks(page) if block.run and block.note in ("python", "console")]


@pytest.mark.parametrize("block", RUNNABLE, ids=[f"{b.source}:{b.line}" for b in RUNNABLE])
def test_the_block_runs(block: Block, tmp_path: Path) -> None:
    """Python blocks run as programs, console blocks as sessions, on the simulator in this
    process (`sim:virtual`: the tests' $BIOSCARA_BUS)."""
    assert os.environ["BIOSCARA_BUS"] == "sim:virtual"
    if block.note == "console":
        run_session(steps(block.text), tmp_path)
        return
    result = subprocess.run([sys.executable, "-c", block.text], cwd=tmp_path, capture_output=True, text=True,
                            timeout=COMMAND_TIMEOUT_S * 2, env=os.environ)
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr


def test_every_example_parses() -> None:
    """Each command's EXAMPLES (its --help and the reference show them) is a valid command line."""
    parser = cli.build_parser()
    for module in cli_reference.command_modules():
        for line, what in module.EXAMPLES:
            command = line.rsplit("| ", 1)[-1]  # `printf ... | bioscara shell`: the bioscara part
            words = shlex.split(command)
            assert words[0] == "bioscara" and words[1] == module.NAME, line
            assert what, line
            parser.parse_args(words[1:])  # a usage error exits (SystemExit fails the test)


@pytest.mark.parametrize("markdown", ["see `firmware/joint/no_such_module.py`", "in `core/no_such_module.py`",
                                      "`bioscara.no_such_module`", "`joint.app.no_such_function`",
                                      "<!-- generated: no-such-table -->"])
def test_a_stale_reference_fails_the_build(markdown: str) -> None:
    from mkdocs.exceptions import PluginError

    from docgen import hooks
    page = SimpleNamespace(file=SimpleNamespace(src_uri="page.md"))
    with pytest.raises(PluginError, match="page.md"):
        hooks.on_page_markdown(markdown, page, None, None)  # type: ignore[arg-type]
