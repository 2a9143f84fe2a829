"""Module tables of the firmware and the host package, from each module's own docstring (read
with `ast`, nothing imported: the firmware's modules are MicroPython's), so a module that moves,
appears or is renamed shows up here by itself."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _summary(path: Path) -> str:
    """The docstring's first paragraph on one line ("" without a docstring)."""
    doc = ast.get_docstring(ast.parse(path.read_text(), str(path))) or ""
    return " ".join(doc.split("\n\n")[0].split()).replace("|", "\\|")


def table(root: str, skip: tuple[str, ...] = ()) -> str:
    """`| module | holds |` for every .py under `root` (a package's __init__ first, as the package)."""
    base = ROOT / root
    rows = ["| module | holds |", "|---|---|"]
    for path in sorted(base.rglob("*.py"), key=lambda p: (p.parent.relative_to(base).parts, p.name != "__init__.py", p.name)):
        relative = path.relative_to(base)
        if relative.parts[0] in skip or "__pycache__" in relative.parts:
            continue
        name = f"**`{relative.parent}/`**" if path.name == "__init__.py" else f"`{relative}`"
        if path.name == "__init__.py" and relative.parent == Path("."):
            name = f"**`{root}/`**"
        rows.append(f"| {name} | {_summary(path)} |")
    return "\n".join(rows) + "\n"


def firmware() -> str:
    return table("firmware/joint")


def host() -> str:
    return table("host/bioscara")


def hil_bridge() -> str:
    return table("hil_bridge")
