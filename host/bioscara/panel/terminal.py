"""The panel's terminal driver: Textual's LinuxDriver, made to end cleanly when its terminal goes
away (a closed window, a dropped SSH session).

Two things went wrong there (1 run in 6 of tests/test_panel_terminal.py's closed-terminal case on a
loaded machine, the panel hung for good instead of stopping its joint and exiting):

* Textual's writer thread ends on the first write the terminal refuses (EIO), and after it every
  write waits on its queue of 30, the app's shutdown included. The output here drops what a
  hung-up terminal cannot take instead.
* The kernel sends SIGCONT with SIGHUP when a terminal hangs up, and Textual's handler then started
  the screen again (a second writer and input thread) on a panel that was never suspended. Here
  SIGCONT resumes only after a SIGTSTP suspended it.
"""

from __future__ import annotations

from typing import Any, TextIO

from textual.drivers.linux_driver import LinuxDriver


class HangupSafeOutput:
    """`stream` until a write or flush fails (the terminal is gone); nothing after that."""

    def __init__(self, stream: TextIO) -> None:
        self._stream = stream
        self.gone = False

    def write(self, text: str) -> int:
        if not self.gone:
            try:
                self._stream.write(text)
            except OSError:
                self.gone = True
        return len(text)

    def flush(self) -> None:
        if not self.gone:
            try:
                self._stream.flush()
            except OSError:
                self.gone = True

    def fileno(self) -> int:
        return self._stream.fileno()

    def isatty(self) -> bool:
        return self._stream.isatty()


class PanelDriver(LinuxDriver):
    """LinuxDriver with a HangupSafeOutput, resumed by SIGCONT only after a suspend."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._file = HangupSafeOutput(self._file)
        self._suspended = False

    def _sigtstp_application(self, *args: Any) -> None:
        self._suspended = True
        super()._sigtstp_application(*args)

    def _sigcont_application(self, *args: Any) -> None:
        if self._suspended:
            self._suspended = False
            super()._sigcont_application(*args)
