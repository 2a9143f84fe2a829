"""MkDocs hooks (mkdocs.yml `hooks:`): the generated sections and pictures of the site.

A page asks for a generated section with `<!-- generated: NAME -->` alone on a line; an unknown
name, or a generator that fails, fails the build. Pictures are added as generated files, so the
strict build checks every link to them and nothing generated is committed.
"""

from __future__ import annotations

import importlib
import re
from collections.abc import Callable

from mkdocs.config.defaults import MkDocsConfig
from mkdocs.exceptions import PluginError
from mkdocs.structure.files import File, Files
from mkdocs.structure.pages import Page

from docgen import cli_reference, errors_reference, layout, pictures, protocol_reference

SECTIONS: dict[str, Callable[[], str]] = {
    "commands": cli_reference.markdown,
    "protocol-facts": protocol_reference.facts,
    "flags": protocol_reference.flags,
    "registers": protocol_reference.registers,
    "error-codes": protocol_reference.error_codes,
    "reject-reasons": protocol_reference.reject_reasons,
    "v2-map": protocol_reference.v2_map,
    "exceptions": errors_reference.exceptions,
    "host-messages": errors_reference.messages,
    "reject-causes": errors_reference.reject_reasons,
    "verdict-causes": errors_reference.verdicts,
    "firmware-layout": layout.firmware,
    "host-layout": layout.host,
    "hil-bridge-layout": layout.hil_bridge,
}
MARKER = re.compile(r"^<!-- generated: ([\w-]+) -->$", re.M)
# A repository path in backquotes: it must exist, so a moved or renamed module fails the build.
PATH = re.compile(r"`((?:firmware|host|hil_bridge|tests|bench|chip|docgen)/[\w./-]*[\w/])(?:::\w+)?`")
# A file named by its path inside a package (`core/irq.py`, `test_stall.py`): some file of the
# project must end with it. Board paths (`/main.py`, `joint/core.mpy`) are not the project's.
MODULE = re.compile(r"`([\w/]*\w\.(?:py|json|mjs))`")
BOARD_PATHS = {"main.py", "code.py", "boot.py", "boot_out.txt", "joint_config.json", "bridge_config.json"}
# A dotted name of the host package or of the firmware as the board imports it (`joint.spec`):
# it must import (then resolve attribute by attribute).
DOTTED = re.compile(r"`((?:bioscara|joint)(?:\.\w+)+)(?:\(\))?`")
ROOT = pictures.ROOT
SOURCES = ("firmware", "host", "hil_bridge", "tests", "bench", "chip/src", "chip/test", "chip", "docgen")


def _project_files() -> set[str]:
    files = set()
    for top in SOURCES:
        for path in (ROOT / top).rglob("*"):
            if path.suffix in (".py", ".json", ".mjs") and "node_modules" not in path.parts:
                files.add(path.relative_to(ROOT).as_posix())
    return files


def _resolves(name: str) -> bool:
    parts = name.replace("joint.", "bioscara.firmware.", 1).split(".")
    for end in range(len(parts), 0, -1):
        try:
            found: object = importlib.import_module(".".join(parts[:end]))
        except ImportError:
            continue
        for attribute in parts[end:]:
            if not hasattr(found, attribute):
                return False
            found = getattr(found, attribute)
        return True
    return False


def stale_references(markdown: str) -> list[str]:
    """Backquoted repository paths, module file names and dotted module names in `markdown` that
    name nothing in the project."""
    stale = {path for path in PATH.findall(markdown)
             if ".." not in path and "node_modules" not in path and not (ROOT / path).exists()}
    files = _project_files()
    stale |= {name for name in MODULE.findall(markdown) if name not in BOARD_PATHS and not name.startswith(("/", *SOURCES))
              and not any(f == name or f.endswith("/" + name) for f in files)}
    stale |= {name for name in DOTTED.findall(markdown) if not _resolves(name)}
    return sorted(stale)


def on_files(files: Files, config: MkDocsConfig) -> Files:
    generated = {
        "img/architecture.svg": pictures.architecture(),
        "img/homing.png": pictures.homing_trace(),
        **{f"img/protocol-{name}.svg": svg for name, svg in pictures.protocol_layouts().items()},
    }
    for path, content in generated.items():
        files.append(File.generated(config, path, content=content))
    return files


def on_page_markdown(markdown: str, page: Page, config: MkDocsConfig, files: Files) -> str:
    def section(match: re.Match[str]) -> str:
        name = match.group(1)
        if name not in SECTIONS:
            raise PluginError(f"{page.file.src_uri}: no generated section {name!r} (docgen/hooks.py SECTIONS)")
        try:
            return SECTIONS[name]()
        except Exception as exc:
            raise PluginError(f"{page.file.src_uri}: generating {name!r} failed: {exc}") from exc
    stale = stale_references(markdown)
    if stale:
        raise PluginError(f"{page.file.src_uri} names paths that do not exist: {', '.join(stale)}")
    return MARKER.sub(section, markdown)
