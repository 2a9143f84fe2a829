"""`bioscara panel` as a user starts it, in a pseudo-terminal: seconds to the first screen, and the
process's CPU while idle and while the simulated arm homes (the simulator runs in the panel's own
process, 4 joints at 1 kHz, and is included). Prints `name value` lines; `make bench` runs it."""

from __future__ import annotations

import os
import pty
import select
import shutil
import signal
import sys
import tempfile
import time

WINDOW_S = 5.0


def _cpu_s(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as stat:
        fields = stat.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _read_until(fd: int, marker: bytes, seconds: float) -> bool:
    seen = b""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        ready, _, _ = select.select([fd], [], [], 0.1)
        if ready:
            try:
                seen = (seen + os.read(fd, 65536))[-65536:]
            except OSError:
                return False
            if marker in seen:
                return True
    return False


def _drain(fd: int, seconds: float) -> None:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if select.select([fd], [], [], 0.1)[0]:
            try:
                os.read(fd, 65536)
            except OSError:
                return


def _cpu_share(pid: int, fd: int) -> float:
    before, start = _cpu_s(pid), time.monotonic()
    _drain(fd, WINDOW_S)
    return (_cpu_s(pid) - before) / (time.monotonic() - start) * 100


def main() -> None:
    bioscara = shutil.which("bioscara") or os.path.join(os.path.dirname(sys.executable), "bioscara")
    state = tempfile.mkdtemp()
    start = time.monotonic()
    pid, fd = pty.fork()
    if pid == 0:
        os.environ.update(XDG_STATE_HOME=state, COLUMNS="160", LINES="50", TERM="xterm-256color")
        os.execv(bioscara, [bioscara, "panel"])
    try:
        if not _read_until(fd, b"Configure", 60):
            raise SystemExit("the panel did not draw its first screen within 60 s")
        print(f"panel.start_s {time.monotonic() - start:.2f}")
        _drain(fd, 1.0)
        print(f"panel.cpu_idle_pct {_cpu_share(pid, fd):.1f}")
        for key in (b"a", b"a", b"h", b"H"):
            os.write(fd, key)
            _drain(fd, 0.5)
        print(f"panel.cpu_moving_pct {_cpu_share(pid, fd):.1f}")
    finally:
        os.kill(pid, signal.SIGTERM)
        os.waitpid(pid, 0)
        shutil.rmtree(state, ignore_errors=True)


if __name__ == "__main__":
    main()
