"""Helpers for tests that run a user's session against the shared simulated arm (`sim:`): the
service in the test's own state directory, programs started as real processes, bounded waits."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from bioscara import sim_service
from bioscara.config import read_config


@pytest.fixture
def state_dir(private_home: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """The state directory of this test's service; `sim:` is the shared arm here. Stopped at the end."""
    monkeypatch.delenv("BIOSCARA_BUS")
    path = private_home / "state" / "bioscara"
    yield path
    status = sim_service.status(path) if path.exists() else None
    if status is not None and not sim_service.stop(path):
        os.kill(status["pid"], signal.SIGKILL)


def wait_until(condition, timeout: float = 10.0) -> bool:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def quick_config(tmp_path: Path, watchdog_ms: int | None = None) -> Path:
    """The shipped arm with every joint starting just inside the end stop it homes into (real time:
    short). `watchdog_ms`: the joints' host-silence timeout instead of the shipped 100 ms (a
    simulated arm on a machine shared by many busy processes can stall longer than that)."""
    text = (Path(read_config().source)).read_text()
    if watchdog_ms is not None:
        text = re.sub(r"^watchdog_ms = .*\n", "", text, flags=re.M)
        text = re.sub(r"^(\[joints\.j\d\])$", rf"\1\nwatchdog_ms = {watchdog_ms}", text, flags=re.M)
    head, _, _ = text.partition("[sim.start]")
    path = tmp_path / "arm.toml"
    path.write_text(head + "[sim.start]\nj1 = -3.03\nj2 = 0.3375\nj3 = 2.61\nj4 = 2.99\n")
    return path


@pytest.fixture
def bioscara() -> Iterator[Callable[..., subprocess.Popen[str]]]:
    """Starts `bioscara ARGS...` in the background; what still runs at the end is killed."""
    started: list[subprocess.Popen[str]] = []

    def spawn(*argv: str) -> subprocess.Popen[str]:
        started.append(subprocess.Popen([sys.executable, "-m", "bioscara.cli", *argv], stdout=subprocess.PIPE,
                                        stderr=subprocess.PIPE, text=True))
        return started[-1]
    yield spawn
    for process in started:
        if process.poll() is None:
            process.kill()
            process.communicate()
