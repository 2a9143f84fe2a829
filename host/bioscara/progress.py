"""Progress of long work (a move, a homing) on stderr, so stdout keeps only the result.

On a terminal the progress is redrawn in place (rich Live) and goes away at the end; otherwise
(a pipe, a log file, a test reading the process) it is one plain line every `every` seconds.
Imports rich and the communicator only.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from types import TracebackType

from rich.console import Console, RenderableType
from rich.live import Live

from .communicator import Communicator


class Progress:
    """`render()`: what the terminal shows; `line()`: the plain line written when not on a terminal;
    `sample()`, if given, runs at every `show()` (after every cycle) to accumulate figures."""

    def __init__(self, render: Callable[[], RenderableType], line: Callable[[], str], *,
                 every: float = 0.5, console: Console | None = None,
                 sample: Callable[[], None] | None = None) -> None:
        self.console = console or Console(stderr=True)
        self.render = render
        self.line = line
        self.every = every
        self.sample = sample
        self._live: Live | None = None
        self._next = 0.0
        self._unread = False  # the output went away

    def __enter__(self) -> Progress:
        if self.console.is_terminal:
            self._live = Live(self.render(), console=self.console, auto_refresh=False, transient=True)
            self._live.__enter__()
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 traceback: TracebackType | None) -> None:
        live, self._live = self._live, None
        if live is not None:
            with contextlib.suppress(OSError):  # the terminal closed: nothing to clear, and the
                live.__exit__(kind, exc, traceback)  # exception that ends the work stays the one

    def show(self) -> None:
        if self.sample is not None:
            self.sample()
        if self._unread:
            return
        try:
            if self._live is not None:
                self._live.update(self.render(), refresh=True)
                return
            now = time.monotonic()
            if now >= self._next:
                self._next = now + self.every
                print(self.line(), file=self.console.file, flush=True)
        except OSError:
            # Nobody reads any more: the terminal closed (EIO; its SIGHUP stops the work) or the
            # reader left. The work goes on, unshown, rather than ending with its joint moving.
            self._unread = True


class ProgressRunner:
    """A motion runner (see `bioscara.motion.Runner`): runs the communicator and shows the
    progress after every cycle."""

    def __init__(self, comm: Communicator, progress: Progress) -> None:
        self.comm = comm
        self.progress = progress

    def run_until(self, predicate: Callable[[], bool], timeout: float) -> None:
        def check() -> bool:
            self.progress.show()
            return predicate()
        self.comm.run_until(check, timeout)
