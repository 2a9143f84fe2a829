"""The signals that end a command — Ctrl-C (SIGINT), SIGTERM, a closed terminal (SIGHUP) — as one
exception, `Interrupted`, so that whatever moves a joint stops it before the program exits.

`stop_on_signals()` installs the handlers for the length of a command; `stop_arms()` is what the
command line runs when the exception reaches it: STOP to every arm the command activated, and a
line saying where each joint stopped. Imports the arm and the report shapes only.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterable, Iterator

from . import report
from .arm import Arm, Lifecycle
from .errors import BioscaraError, NotHomedError

SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
SETTLE_S = 5.0  # longest deceleration from top speed at the slowest configured deceleration, with margin
AT_REST = 1e-3  # joint units/s
CAUSES = {signal.SIGINT: "Ctrl-C", signal.SIGTERM: "SIGTERM", signal.SIGHUP: "the terminal closed (SIGHUP)"}


class Interrupted(KeyboardInterrupt):
    """A signal that ends the command; `exit_status` is the shell's 128 + the signal's number."""

    def __init__(self, signum: int) -> None:
        super().__init__(CAUSES.get(signal.Signals(signum), signal.Signals(signum).name))
        self.signum = signum

    @property
    def cause(self) -> str:
        return str(self.args[0])

    @property
    def exit_status(self) -> int:
        return 128 + self.signum


def exit_status(exc: KeyboardInterrupt) -> int:
    """130 for a plain KeyboardInterrupt (Python's own Ctrl-C), else the signal's status."""
    return exc.exit_status if isinstance(exc, Interrupted) else 128 + signal.SIGINT


@contextlib.contextmanager
def stop_on_signals() -> Iterator[None]:
    """Raise `Interrupted` in the main thread on SIGINT, SIGTERM or SIGHUP. A signal the process
    ignores stays ignored (nohup, a background job). After the first signal the others are held
    off until the block ends, so a second Ctrl-C cannot break off the stop that follows the first.
    Outside the main thread (an embedding program's worker) nothing is installed."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous: dict[int, Callable[..., object] | int | None] = {}
    fired: list[int] = []

    def interrupt(signum: int, frame: object) -> None:
        if fired:
            return
        fired.append(signum)
        raise Interrupted(signum)

    for signum in SIGNALS:
        if signal.getsignal(signum) is not signal.SIG_IGN:
            previous[signum] = signal.signal(signum, interrupt)
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler if handler is not None else signal.SIG_DFL)


def stop_arms(arms: Iterable[Arm], say: Callable[[str], None], settle: float = SETTLE_S) -> None:
    """STOP every joint of each arm that is active (this command drives it), wait until the joints
    are at rest (at most `settle` s: the firmware decelerates), then say where each one stopped.
    An arm this command only watched is left alone: it may be another program's."""
    for arm in arms:
        if arm.lifecycle is not Lifecycle.ACTIVE:
            continue
        try:
            arm.stop()
            _wait_at_rest(arm, settle)
        except BioscaraError as exc:
            say(f"could not stop every joint: {exc}")
        where = []
        for name, aj in arm.joints.items():
            try:
                where.append(f"{name} at {report.value(aj.joint.get_position(), aj.config)}")
            except NotHomedError:
                where.append(f"{name} (not homed)")
            except BioscaraError as exc:
                where.append(f"{name} position unknown ({exc.detail})")
        say(f"stopped {', '.join(where)}")


def _wait_at_rest(arm: Arm, settle: float) -> None:
    deadline = arm.bus.monotonic() + settle
    while arm.bus.monotonic() < deadline:
        if all(abs(aj.joint.get_velocity()) < AT_REST for aj in arm.joints.values()):
            return
        arm.bus.sleep(0.02)
