"""What a command-line invocation works with: the configuration, the bus, the arm, the output."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from typing import Any

from rich.console import Console

from . import report
from .arm import Arm, make_joint
from .bus import Bus
from .config import ArmConfig, load_config
from .errors import BioscaraError, InvalidArgumentError
from .hardware import open_arm, open_arm_bus
from .joint import Joint


class Session:
    """Lazily opens what a command needs, from `--config` and `--bus`; closes it at the end."""

    def __init__(self, args: argparse.Namespace, bus: Bus | None = None) -> None:
        self.args = args
        self.json = bool(getattr(args, "json", False))
        self.console = Console(stderr=self.json)
        if not self.console.is_terminal:  # piped: whole lines, not wrapped at 80 columns
            self.console = Console(stderr=self.json, width=200)
        self._config: ArmConfig | None = None
        self._bus = bus
        self._owns_bus = bus is None
        self._arm: Arm | None = None
        self._opened: list[Arm | Joint] = []  # released at close()
        self.arms: list[Arm] = []  # stopped when a signal ends the command (interruption.stop_arms)

    @property
    def config(self) -> ArmConfig:
        if self._config is None:
            self._config = load_config(getattr(self.args, "config", None), getattr(self.args, "bus", None))
        return self._config

    @property
    def bus(self) -> Bus:
        if self._bus is None:
            self._bus = open_arm_bus(self.config)
            commander = self._bus.commander
            if commander is not None and getattr(self.args, "take_over", False):
                commander.take_over = True  # --take-over: stop the program that commands, then command
        return self._bus

    @property
    def arm(self) -> Arm:
        """The whole arm, commanded by this program (configuring it makes this program the
        bus's commander: ArmBusyError while another one is)."""
        if self._arm is None:
            self._arm = self._keep(open_arm(self.config, self.bus, self.protocol))
        return self._arm

    def watched_arm(self) -> Arm:
        """The whole arm, only read: beside any program that commands it (commander.py)."""
        self._watching()
        return self._keep(open_arm(self.config, self.bus, watch=True))

    def _watching(self) -> None:
        """A reading command reads the legacy map (or the commanding program's state): it never
        switches a joint to v2, which would take the joint from whoever commands it."""
        if self.protocol == "v2":
            raise InvalidArgumentError("this command only reads, in the legacy map or from the program that "
                                       "commands the arm: --protocol v2 does not apply")

    def _keep(self, what: Any) -> Any:
        self._opened.append(what)
        if isinstance(what, Arm):
            self.arms.append(what)
        return what

    def drives(self, arm: Arm) -> Arm:
        """An arm the command opened itself (shell, panel): stopped like the session's own on a signal."""
        self.arms.append(arm)
        return arm

    @property
    def protocol(self) -> str:
        """--protocol: auto, legacy or v2."""
        return str(getattr(self.args, "protocol", None) or "auto")

    def joint(self, name: str, *, watch: bool = False) -> Joint:
        """An initialized joint by name (j1..j4, or J1..J4); `watch`: only read (commander.py)."""
        name = name.lower()
        if name not in self.config.joints:
            raise InvalidArgumentError(f"no joint {name!r}; the configuration has {', '.join(self.config.joints)}")
        if watch:
            self._watching()
        joint = self._keep(make_joint(self.config.joints[name], self.bus, watch))
        joint.init()
        return joint

    def emit(self, data: Any, human: Any = None) -> None:
        """Print `data` as JSON with --json, else `human` (a rich renderable or text) or `data`."""
        if self.json:
            sys.stdout.write(json.dumps(data, default=str) + "\n")
        else:
            self.console.print(report.for_terminal(human if human is not None else data, self.console.is_terminal))

    def err(self, message: str) -> None:
        """One message on stderr; dropped when nobody can read it any more (the terminal closed:
        EIO; the reader left: EPIPE), so the stop and the release that follow still run."""
        try:
            Console(stderr=True, soft_wrap=True).print(message, style="red", markup=False, highlight=False)
        except OSError:
            pass

    def fail(self, exc: BioscaraError | OSError, status: int) -> None:
        """Report the error that ends the command: one line on stderr, `error: [JOINT: ]what`."""
        self.err(f"error: {exc.message if isinstance(exc, BioscaraError) else exc}")

    def arm_of(self, names: list[str]) -> Arm:
        """An arm made of some of the configured joints (commands act on those only)."""
        names = [name.lower() for name in names]
        unknown = [name for name in names if name not in self.config.joints]
        if unknown:
            raise InvalidArgumentError(f"no joint {', '.join(unknown)}; the configuration has {', '.join(self.config.joints)}")
        config = replace(self.config, joints={name: self.config.joints[name] for name in names})
        return self._keep(open_arm(config, self.bus, self.protocol))

    def close(self) -> None:
        """Release the joints and the bus. Joints keep their state: a joint that was moved keeps
        holding, and the next command (of any host) finds it in the legacy map."""
        for opened in reversed(self._opened):
            try:
                if isinstance(opened, Arm):
                    opened.release()
                else:
                    opened.close()
            except BioscaraError:
                pass  # the bus is gone: the joint falls back by itself (host silence)
        self._opened.clear()
        if self._bus is not None and self._owns_bus:
            self._bus.close()
