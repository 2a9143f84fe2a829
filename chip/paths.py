"""Where the emulated Pico's pieces are, and what is missing to run it (for clear test skips)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

CHIP_DIR = Path(__file__).resolve().parent
REPO = CHIP_DIR.parent
UF2_NAME = "micropython-v1.28.0-RPI_PICO.uf2"
CIRCUITPYTHON_UF2_NAME = "circuitpython-10.2.1-raspberry_pi_pico.uf2"
BOOTROM_NAME = "rp2040-bootrom-B1.bin"
RUNTIMES = {"micropython": UF2_NAME, "circuitpython": CIRCUITPYTHON_UF2_NAME}  # each one's stock UF2


def _main_checkout(repo: Path) -> Path | None:
    """The main checkout when `repo` is a git worktree of it (`.git` is then a file)."""
    dot_git = repo / ".git"
    if not dot_git.is_file():
        return None
    text = dot_git.read_text()
    if not text.startswith("gitdir:"):
        return None
    gitdir = Path(text.split(":", 1)[1].strip())
    common = (gitdir / (gitdir / "commondir").read_text().strip()).resolve()
    return common.parent


def rp2040_dir() -> Path:
    """$BIOSCARA_RP2040, else ../shared/rp2040 beside the repository (or beside its main checkout)."""
    if os.environ.get("BIOSCARA_RP2040"):
        return Path(os.environ["BIOSCARA_RP2040"]).resolve()
    candidates = [REPO.parent / "shared" / "rp2040"]
    main = _main_checkout(REPO)
    if main is not None:
        candidates.append(main.parent / "shared" / "rp2040")
    return next((d for d in candidates if (d / UF2_NAME).exists()), candidates[0])


def missing(runtime: str = "micropython") -> str | None:
    """Why the emulated Pico cannot run `runtime` here, naming the missing piece; None if it can."""
    if shutil.which("node") is None:
        return "node is not installed (the emulated Pico runs on node, https://nodejs.org)"
    if not (CHIP_DIR / "node_modules" / "rp2040js").is_dir():
        return "chip/node_modules is missing: run make (it runs npm ci --prefix chip)"
    directory = rp2040_dir()
    absent = [name for name in (RUNTIMES[runtime], BOOTROM_NAME) if not (directory / name).exists()]
    if absent:
        return f"{', '.join(absent)} missing in {directory} (see ../shared/rp2040/README.md)"
    return None
