"""Where bioscara keeps its files on the host."""

from __future__ import annotations

import os
from pathlib import Path


def _xdg(variable: str, fallback: str) -> Path:
    """$variable/bioscara, or ~/fallback/bioscara when it is unset or not absolute (the XDG rule)."""
    xdg = os.environ.get(variable, "")
    base = Path(xdg) if os.path.isabs(xdg) else Path.home() / fallback
    return base / "bioscara"


def default_state_dir() -> Path:
    """$XDG_STATE_HOME/bioscara (~/.local/state/bioscara): history, gripper position, the simulator."""
    return _xdg("XDG_STATE_HOME", ".local/state")


def default_config_dir() -> Path:
    """$XDG_CONFIG_HOME/bioscara (~/.config/bioscara): the user's arm configuration."""
    return _xdg("XDG_CONFIG_HOME", ".config")


def private_dir(path: Path) -> Path:
    """`path`, created if needed, readable by this user only (0700)."""
    path.mkdir(mode=0o700, parents=True, exist_ok=True)
    if path.stat().st_mode & 0o077:
        path.chmod(0o700)
    return path


def private_file(path: Path) -> Path:
    """`path`, created empty if needed, readable by this user only (0600); its directory too if new."""
    if not path.parent.exists():
        private_dir(path.parent)
    os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o600))
    if path.stat().st_mode & 0o077:
        path.chmod(0o600)
    return path
