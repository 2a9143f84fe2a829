"""The `bioscara shell` interpreter: console commands for the communicator, the arm and raw registers.

In the spirit of the IgH EtherCAT master's keyboard controller (`!start`, `!stop`, `!restart`,
`!variable`, `!run`): `Shell.execute(line)` runs one command against a context (configuration, bus,
arm) and prints through the output functions it was given. It knows nothing about terminals: the
line editor (history, Ctrl-C, tab completion through `Shell.complete`) is in
`bioscara.commands.shell`.

Units: joint positions in rad (revolute) or m (prismatic), velocities in units/s, times on the bus
clock in s; register values in the units the protocol spec declares for each field.
"""

from __future__ import annotations

import difflib
import glob
import math
import os
import shlex
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any, Protocol

from .arm import Arm, Lifecycle, Mode, make_joint
from .bus.base import Bus
from .communicator import Communicator
from .config import ArmConfig
from .errors import (BioscaraError, CommError, InvalidArgumentError, NotEnabledError, StalledError)
from .firmware.spec import protocol as P
from .joint import Joint

Output = Callable[[str], None]

ALL = "all"  # joint argument meaning every joint of the arm, as the IgH console's 'all' slave
OFF = "off"  # `mode JOINT off`: no command mode
_KINDS = {P.U8: "u8", P.I32: "i32", P.F32: "f32", P.U16: "u16", P.U32: "u32", P.CHAR: "char"}
_I32_MIN, _I32_MAX = -(2 ** 31), 2 ** 31 - 1


class ShellContext(Protocol):
    """What the shell works on; `bioscara.session.Session` is one."""

    @property
    def config(self) -> ArmConfig: ...

    @property
    def bus(self) -> Bus: ...

    @property
    def arm(self) -> Arm: ...


NOT_UTF8 = "\ufffe not UTF-8"  # stands for a script line that could not be decoded


def script_lines(source: Path | Any) -> list[str]:
    """The lines of a script file (or a binary stream); an undecodable line becomes NOT_UTF8, which
    fails where it stands. InvalidArgumentError if the file cannot be read."""
    if isinstance(source, Path):
        try:
            raw = source.read_bytes()
        except OSError as exc:
            raise InvalidArgumentError(f"cannot read {source}: {exc.strerror or exc}") from None
        chunks = raw.splitlines()
    else:
        chunks = list(source)
    lines = []
    for chunk in chunks:
        try:
            lines.append(chunk.decode("utf-8").rstrip("\r\n"))
        except UnicodeDecodeError:
            lines.append(NOT_UTF8)
    return lines


def fault_cause(exc: BioscaraError) -> str:
    """An arm fault with its cause named: deadman, stall, limit or lost link."""
    where = f"{exc.joint}: " if exc.joint else ""
    if isinstance(exc, StalledError):
        return f"{where}stall: stall detection stopped the joint (a collision, or more load than its current)"
    if isinstance(exc, NotEnabledError):
        return (f"{where}deadman: the joint stopped and disabled itself: {exc.detail} "
                "(keep the communicator running while a joint moves)")
    if isinstance(exc, CommError):
        return f"{where}lost link: {exc.detail}"
    if isinstance(exc, InvalidArgumentError) and "outside" in exc.detail:
        return f"{where}limit: {exc.detail}"
    return f"{where}{exc.detail}"


class ShellError(Exception):
    """A command the shell refuses (usage, unknown name, bad value); nothing was sent."""


class _Failed(Exception):
    """A command failed and has already said why (a script run by `run`)."""


class Arg(Enum):
    """What a command's argument completes to."""

    JOINT = "joint"
    READABLE = "readable register"
    WRITABLE = "writable register"
    REGISTER = "register"
    MODE = "mode"
    MODE_OR_OFF = "mode or off"
    COMMAND = "command"
    FILE = "file"


@dataclass(frozen=True)
class Command:
    name: str
    usage: str  # arguments after the name
    summary: str
    details: str
    args: tuple[Arg, ...]
    handler: Callable[[Shell, list[str]], None]


COMMANDS: dict[str, Command] = {}
ALIASES = {"exit": "quit", "?": "help"}


def command(usage: str, summary: str, details: str = "", args: tuple[Arg, ...] = ()
            ) -> Callable[[Callable[[Shell, list[str]], None]], Callable[[Shell, list[str]], None]]:
    """Register a `Shell` method `_do_<name>` as the console command <name>."""
    def register(handler: Callable[[Shell, list[str]], None]) -> Callable[[Shell, list[str]], None]:
        name = handler.__name__.removeprefix("_do_")
        COMMANDS[name] = Command(name, usage, summary, details, args, handler)
        return handler
    return register


class Shell:
    """Console commands on one arm. `execute` runs a line, `run_lines` a script, `complete` completes.

    `expert` allows `write` (raw register frames past the API's guards); `frequency` (Hz) and
    `priority` (SCHED_FIFO priority, None for normal scheduling) configure the communicator.
    """

    def __init__(self, context: ShellContext, out: Output, err: Output | None = None, *,
                 expert: bool = False, frequency: float = 100.0, priority: int | None = 50,
                 keep_alive: bool = False) -> None:
        self.context = context
        self.out = out
        self.err = err or out
        self.expert = expert
        self.priority = priority
        # On a bus in real time the joints' deadman (50 ms) would disable an active joint between
        # two typed lines: the communicator thread then runs whenever the arm is active.
        self.keep_alive = keep_alive
        self.communicator = Communicator(context.arm, frequency, realtime_priority=priority)
        self.done = False
        self._probes: dict[str, Joint] = {}
        self._reported_fault = context.arm.fault
        self._scripts: list[Path] = []

    @property
    def arm(self) -> Arm:
        return self.context.arm

    def prompt(self) -> str:
        """The prompt: lifecycle, and the rate while the communicator runs."""
        rate = f" @{self.communicator.frequency:g}Hz" if self.communicator.running else ""
        return f"bioscara[{self.arm.lifecycle.value}{rate}]> "

    def close(self) -> None:
        """Stop the communicator thread (the caller shuts the arm down and closes the bus)."""
        self.communicator.stop()

    # ---- running lines ----

    def execute(self, line: str, where: str = "") -> bool:
        """Run one console line; False if it failed (the reason is printed, prefixed by `where`)."""
        prefix = f"{where}: " if where else ""
        if line == NOT_UTF8:
            self.err(f"{prefix}error: not UTF-8 text; nothing was run")
            return False
        try:
            words = shlex.split(line, comments=True)
        except ValueError as exc:
            self.err(f"{prefix}error: {exc}")
            return False
        if not words:
            return True
        try:
            cmd = self._command(words[0])
            cmd.handler(self, words[1:])
        except _Failed:
            return False
        except (ShellError, BioscaraError, OSError, ValueError) as exc:
            self.err(f"{prefix}error: {exc}")
            return False
        return self._report_fault(prefix)

    def run_lines(self, lines: Iterable[str], source: str, *, keep_going: bool = False,
                  echo: bool = True) -> bool:
        """Run console lines (a script); stops at the first failure unless `keep_going`.

        Failures are reported as `source:LINE: error: ...`. True if every line succeeded.
        """
        ok = True
        for number, line in enumerate(lines, 1):
            line = line.rstrip("\n")
            if echo and line.strip() and not line.lstrip().startswith("#") and line != NOT_UTF8:
                self.out(f"> {line.strip()}")
            if not self.execute(line, f"{source}:{number}"):
                ok = False
                if not keep_going:
                    break
            if self.done:
                break
        return ok

    def _report_fault(self, prefix: str) -> bool:
        """A fault the communicator met since the last command fails this one (and stops a script)."""
        fault = self.arm.fault
        if fault is None or fault is self._reported_fault:
            return True
        self._reported_fault = fault
        self.err(f"{prefix}error: arm fault, joints disabled (arm {self.arm.lifecycle.value}): "
                 f"{fault_cause(fault)}")
        return False

    @staticmethod
    def _command(name: str) -> Command:
        name = ALIASES.get(name.lower(), name.lower())
        if name not in COMMANDS:
            raise ShellError(f"unknown command {name!r}{_did_you_mean(name, COMMANDS)}; `help` lists them")
        return COMMANDS[name]

    # ---- completion ----

    def complete(self, text: str) -> list[str]:
        """Candidates for the word being typed at the end of `text` (the line up to the cursor)."""
        words = text.split()
        if not words or text[-1].isspace():
            words.append("")
        word, position = words[-1], len(words) - 1
        if position == 0:
            return _matching(word, [*COMMANDS, "exit"])
        cmd = COMMANDS.get(ALIASES.get(words[0].lower(), words[0].lower()))
        if cmd is None or not cmd.args:
            return []
        if position <= len(cmd.args):
            kind = cmd.args[position - 1]
        elif cmd.args[-1] is Arg.FILE:  # after options such as `run --keep-going`
            kind = Arg.FILE
        else:
            return []
        if kind is Arg.FILE:
            return _paths(word)
        return _matching(word, self._candidates(kind))

    def _candidates(self, kind: Arg) -> list[str]:
        if kind is Arg.JOINT:
            return [*self.context.config.joints, ALL]
        if kind is Arg.COMMAND:
            return list(COMMANDS)
        if kind in (Arg.MODE, Arg.MODE_OR_OFF):
            return [m.value for m in Mode] + ([OFF] if kind is Arg.MODE_OR_OFF else [])
        if kind is Arg.READABLE:
            return [r.name for r in P.REGISTERS if r.readable]
        if kind is Arg.WRITABLE:
            return [r.name for r in P.REGISTERS if r.writable]
        return [r.name for r in P.REGISTERS]

    # ---- communicator ----

    @command("[HZ]", "start the communicator thread (read/write cycle; default rate: --rate)",
             "Cycles the arm at HZ (default: the current rate, 100 Hz unless --rate) on a thread,\n"
             "with SCHED_FIFO priority when permitted. A new rate starts fresh statistics.")
    def _do_start(self, args: list[str]) -> None:
        _arity(args, 0, 1, "start [HZ]")
        hz = _number(args[0], "HZ") if args else None
        comm = self.communicator
        if comm.running:
            if hz is not None and hz != comm.frequency:
                raise ShellError(f"the communicator is running at {comm.frequency:g} Hz; `stop` it to change the rate")
            self.out(f"communicator already running at {comm.frequency:g} Hz")
            return
        if hz is not None and hz != comm.frequency:
            self.communicator = Communicator(self.arm, hz, realtime_priority=self.priority)
        self.communicator.reset_stats()  # `stats` counts from here
        self.communicator.start()
        self.out(f"communicator started at {self.communicator.frequency:g} Hz on {self.context.bus.describe()}")

    @command("", "stop the communicator thread")
    def _do_stop(self, args: list[str]) -> None:
        _arity(args, 0, 0, "stop")
        if not self.communicator.running:
            self.out("communicator already stopped")
            return
        self.communicator.stop()
        self.out(f"communicator stopped after {self.communicator.stats.cycles} cycles")
        if self.arm.lifecycle is Lifecycle.ACTIVE:
            self.err("warning: the arm is active: a joint that is moving stops and disables itself once its "
                     "deadman (50 ms without traffic) fires; `start` or `wait` keep the joints fed")

    @command("", "stop and start the communicator thread (keeps the rate, resets the statistics)")
    def _do_restart(self, args: list[str]) -> None:
        _arity(args, 0, 0, "restart")
        self.communicator.stop()
        self.communicator.reset_stats()
        self.communicator.start()
        self.out(f"communicator restarted at {self.communicator.frequency:g} Hz")

    @command("", "communicator timing (rate, jitter, overruns, cycle duration, scheduling) and link health",
             "Timing is on the bus clock (virtual time on a simulated bus not in real-time mode).\n"
             "Per joint: I2C transactions, failed attempts (retried), transactions lost after\n"
             "every retry, and the last error.")
    def _do_stats(self, args: list[str]) -> None:
        _arity(args, 0, 0, "stats")
        comm, stats = self.communicator, self.communicator.stats
        state = "running" if comm.running else "stopped"
        self.out(f"communicator {state}, target {comm.frequency:g} Hz, scheduling: {comm.scheduling}")
        if stats.cycles:
            periods = (f", period {stats.period_min * 1e3:.3f}..{stats.period_max * 1e3:.3f} ms"
                       if stats.cycles > 1 else "")
            self.out(f"  {stats.cycles} cycles, rate {stats.rate:.2f} Hz, jitter {stats.jitter * 1e6:.0f} us"
                     f"{periods}, {stats.overruns} overruns, {stats.errors} cycle errors")
            self.out(f"  cycle duration mean {stats.duration_mean * 1e3:.3f} ms, "
                     f"max {stats.duration_max * 1e3:.3f} ms")
        else:
            self.out("  no cycles yet")
        rows = [["joint", "addr", "transactions", "failed attempts", "lost", "last error"]]
        for name, link in comm.link_health().items():
            address = self.context.config.joints[name].address
            rows.append([name, f"0x{address:02x}", str(link["transactions"]), str(link["failed_attempts"]),
                         str(link["comm_errors"]), str(link["last_error"] or "-")])
        self.out(f"link health, bus {self.context.bus.describe()}")
        for line in _table(rows):
            self.out("  " + line)

    @command("SECONDS", "let the arm cycle for SECONDS (bus clock)",
             "Waits for the running communicator, or runs its cycles in this thread when it is\n"
             "stopped, so scripts can give a homing or a move time to happen.")
    def _do_wait(self, args: list[str]) -> None:
        _arity(args, 1, 1, "wait SECONDS")
        seconds = _number(args[0], "SECONDS")
        if seconds < 0:
            raise ShellError(f"SECONDS must not be negative, got {args[0]}")
        try:
            self.communicator.run_for(seconds)
        except BioscaraError as exc:
            if exc is not self.arm.fault:
                raise  # an arm fault ends the wait; _report_fault describes it

    # ---- lifecycle and commands ----

    @command("", "connect to every joint (arm unconfigured -> inactive)")
    def _do_configure(self, args: list[str]) -> None:
        _arity(args, 0, 0, "configure")
        self.arm.configure()
        self._reported_fault = None
        self.out(f"arm {self.arm.lifecycle.value}")
        self._keep_talking()

    def _keep_talking(self) -> None:
        """With keep-alive, the communicator runs from `configure` on: a joint that has not heard
        its host for a while leaves protocol v2 for the legacy map (and the pause between two typed
        lines is such a while), and an active joint's deadman disables it after 50 ms."""
        if self.keep_alive and not self.communicator.running:
            self.communicator.reset_stats()
            self.communicator.start()
            self.out(f"communicator started at {self.communicator.frequency:g} Hz: it keeps the joints "
                     "fed while you type (the active joints' deadman disables them after 50 ms without traffic)")

    @command("", "enable every joint with its limits (arm inactive -> active)")
    def _do_activate(self, args: list[str]) -> None:
        _arity(args, 0, 0, "activate")
        self.arm.activate()
        self.out(f"arm {self.arm.lifecycle.value}")
        self._keep_talking()

    @command("", "disable every joint, freewheeling (arm active -> inactive)")
    def _do_deactivate(self, args: list[str]) -> None:
        _arity(args, 0, 0, "deactivate")
        self.arm.deactivate()
        self.out(f"arm {self.arm.lifecycle.value}")

    @command("", "disconnect from the joints (arm inactive -> unconfigured)")
    def _do_cleanup(self, args: list[str]) -> None:
        _arity(args, 0, 0, "cleanup")
        self.arm.cleanup()
        self.out(f"arm {self.arm.lifecycle.value}")

    @command("", "lifecycle, and per joint: flags, command mode, state and command values",
             "Values are those of the last cycle (start the communicator or `wait` to refresh them).")
    def _do_state(self, args: list[str]) -> None:
        _arity(args, 0, 0, "state")
        arm, comm = self.arm, self.communicator
        last = comm.last
        cycle = (f"cycle #{last.cycle} at t = {last.time:.3f} s" if last is not None
                 else "no cycle yet: `start` or `wait` refresh them")
        running = f"running at {comm.frequency:g} Hz" if comm.running else "stopped"
        self.out(f"arm {arm.lifecycle.value}, communicator {running}; values of the last read ({cycle})")
        if arm.fault is not None:
            self.out(f"fault: {arm.fault}")
        rows = [["joint", "flags", "mode", "position", "velocity", "homed", "cmd position", "cmd velocity",
                 "cmd home"]]
        for name, aj in arm.joints.items():
            unit = "rad" if aj.config.type == "revolute" else "m"
            flags = P.describe_flags(aj.joint.flags) if aj.joint.is_open else "?"
            rows.append([name, flags, _modes(aj.modes), _quantity(aj.state.position, unit),
                         _quantity(aj.state.velocity, f"{unit}/s"), "yes" if aj.state.home == 1.0 else "no",
                         _quantity(aj.command.position, unit), _quantity(aj.command.velocity, f"{unit}/s"),
                         f"{aj.command.home:+g}"])
        for line in _table(rows):
            self.out(line)
        for name, aj in arm.joints.items():
            if aj.joint.disabled_cause and not aj.joint.is_enabled():
                self.out(f"{name}: {aj.joint.disabled_cause}")

    @command("JOINT|all [position|velocity|home|off]", "show or switch a joint's command mode",
             "Switches through the arm's command interfaces: the joint's active mode is stopped and\n"
             "MODE started (position holds the measured position, stopping velocity commands 0,\n"
             "home disables the joint until `set JOINT home +1|-1`). Position and velocity need a\n"
             "homed joint. `off` stops every mode.", (Arg.JOINT, Arg.MODE_OR_OFF))
    def _do_mode(self, args: list[str]) -> None:
        _arity(args, 1, 2, "mode JOINT|all [position|velocity|home|off]")
        names = self._joint_names(args[0])
        if len(args) == 1:
            for name in names:
                self.out(f"{name}: {_modes(self.arm[name].modes)}")
            return
        mode = args[1].lower()
        if mode != OFF:
            _mode(mode)
        start: list[str] = []
        stop: list[str] = []
        for name in names:
            active = [m.value for m in self.arm[name].modes]
            if mode not in active:
                stop += [f"{name}/{m}" for m in active]
                if mode != OFF:
                    start.append(f"{name}/{mode}")
        self.arm.switch_modes(start=start, stop=stop)
        self.out(f"{', '.join(names)}: {mode}")

    @command("JOINT|all position|velocity|home VALUE", "set a command value (sent by the next cycle)",
             "position in rad or m within the joint's limits, velocity in rad/s or m/s up to its\n"
             "max_velocity, home +1 or -1 to home toward that end stop (0 aborts). The value is sent\n"
             "by each cycle while the joint is in that mode.", (Arg.JOINT, Arg.MODE))
    def _do_set(self, args: list[str]) -> None:
        _arity(args, 3, 3, "set JOINT|all position|velocity|home VALUE")
        names = self._joint_names(args[0])
        mode = _mode(args[1].lower())
        value = _number(args[2], "VALUE")
        for name in names:  # all of them first: `set all` changes every joint or none
            self.arm.check_command(name, mode.value, value)
        for name in names:
            self.arm.set_command(name, mode.value, value)
        idle = [name for name in names if mode not in self.arm[name].modes]
        note = f" (not in {mode.value} mode: {', '.join(idle)})" if idle else ""
        self.out(f"{', '.join(names)}: {mode.value} command {value:g}{note}")

    # ---- registers ----

    @command("JOINT|all REGISTER", "read a register, decoded with the spec's units",
             "Any readable register (see `regs`). A joint the arm has not configured is opened\n"
             "first (one PING).", (Arg.JOINT, Arg.READABLE))
    def _do_read(self, args: list[str]) -> None:
        _arity(args, 2, 2, "read JOINT|all REGISTER")
        names = self._joint_names(args[0])
        reg = _register(args[1])
        if not reg.readable:
            raise _unusable(reg, "read")
        for name in names:
            joint = self._joint(name)
            values = joint.read_register(reg.name)
            fields = ", ".join(_format_field(reg, f, v) for f, v in zip(reg.read, values))
            self.out(f"{name} {reg.name}: {fields}  [{P.describe_flags(joint.flags)}]")

    @command("JOINT|all REGISTER VALUE...", "write a raw register frame (needs --expert)",
             "Sends the frame as is, past the API's guards (limits, enabled and homed checks), so it\n"
             "is refused unless the shell was started with --expert. The values are still checked\n"
             "against the spec's ranges first: a bad value sends nothing.", (Arg.JOINT, Arg.WRITABLE))
    def _do_write(self, args: list[str]) -> None:
        if not self.expert:
            raise ShellError("raw register writes bypass the arm's guards and are refused; "
                             "start the shell with `bioscara shell --expert` to allow them")
        if len(args) < 2:
            raise ShellError("usage: write JOINT|all REGISTER VALUE...")
        names = self._joint_names(args[0])
        reg = _register(args[1])
        if not reg.writable:
            raise _unusable(reg, "written")
        values = _parse_values(reg, args[2:])
        for name in names:
            flags = self._joint(name).write_register(reg.name, *values)
            shown = " ".join(str(v) for v in values)
            self.out(f"{name} {reg.name} {shown}: accepted  [{P.describe_flags(flags)}]")

    @command("[REGISTER]", "list the registers: direction, layout, units, ranges",
             "Without REGISTER, one line per register: address, name, R/W, write fields (type,\n"
             "valid range, unit) and read fields. With REGISTER, its details.", (Arg.REGISTER,))
    def _do_regs(self, args: list[str]) -> None:
        _arity(args, 0, 1, "regs [REGISTER]")
        if args:
            for line in _describe_register(_register(args[0])):
                self.out(line)
            return
        rows = [["addr", "register", "dir", "layout"]]
        rows += [[f"0x{r.addr:02x}", r.name, _direction(r), _layout(r)] for r in P.REGISTERS]
        for line in _table(rows):
            self.out(line)

    def _joint_names(self, word: str) -> list[str]:
        names = list(self.context.config.joints)
        word = word.lower()
        if word == ALL:
            return names
        if word not in names:
            raise ShellError(f"no joint {word!r}; the arm has {', '.join(names)} (or {ALL})")
        return [word]

    def _joint(self, name: str) -> Joint:
        """The arm's joint while the arm has it open (so its flags stay current), else a probe."""
        joint = self.arm[name].joint
        if joint.is_open:
            return joint
        if name not in self._probes:
            probe = make_joint(self.context.config.joints[name], self.context.bus)
            probe.init()
            self._probes[name] = probe
        return self._probes[name]

    # ---- scripts and the console ----

    @command("[--keep-going] FILE", "run a file of console commands",
             "One command per line; # starts a comment. Stops at the first failing line (reported\n"
             "as FILE:LINE) unless --keep-going. Relative paths are from the working directory.",
             (Arg.FILE,))
    def _do_run(self, args: list[str]) -> None:
        keep_going = "--keep-going" in args
        files = [a for a in args if a != "--keep-going"]
        if len(files) != 1:
            raise ShellError("usage: run [--keep-going] FILE")
        path = Path(files[0])
        if path.resolve() in self._scripts:
            raise ShellError(f"{path} is already running (a script cannot run itself)")
        if path.is_dir():
            raise ShellError(f"{path} is a directory, not a script")
        try:
            lines = script_lines(path)
        except InvalidArgumentError as exc:
            raise ShellError(exc.detail) from None
        self._scripts.append(path.resolve())
        try:
            ok = self.run_lines(lines, str(path), keep_going=keep_going)
        finally:
            self._scripts.pop()
        if not ok:
            raise _Failed

    @command("[COMMAND]", "list the commands, or explain one", args=(Arg.COMMAND,))
    def _do_help(self, args: list[str]) -> None:
        _arity(args, 0, 1, "help [COMMAND]")
        if args:
            cmd = self._command(args[0])
            self.out(f"{cmd.name} {cmd.usage}".rstrip() + f": {cmd.summary}")
            for line in cmd.details.splitlines():
                self.out("  " + line)
            return
        rows = [[f"{c.name} {c.usage}".rstrip(), c.summary] for c in COMMANDS.values()]
        for line in _table(rows):
            self.out(line)
        self.out("Tab completes commands, joints, registers and modes; Ctrl-C cancels the line; "
                 "`help COMMAND` explains one.")

    @command("", "leave the shell (also exit, Ctrl-D); moving joints are stopped and keep holding")
    def _do_quit(self, args: list[str]) -> None:
        _arity(args, 0, 0, "quit")
        self.done = True


# ---- argument checks ----

def _arity(args: Sequence[str], least: int, most: int, usage: str) -> None:
    if not least <= len(args) <= most:
        raise ShellError(f"usage: {usage}")


def _number(word: str, what: str) -> float:
    try:
        value = float(word)
    except ValueError:
        raise ShellError(f"{what} must be a number, got {word!r}") from None
    if not math.isfinite(value):
        raise ShellError(f"{what} must be finite, got {word!r}")
    return value


def _mode(word: str) -> Mode:
    try:
        return Mode(word)
    except ValueError:
        raise ShellError(f"no command mode {word!r}; use {', '.join(m.value for m in Mode)}") from None


def _register(word: str) -> P.Register:
    reg = P.BY_NAME.get(word.upper())
    if reg is None:
        raise ShellError(f"no register {word!r}{_did_you_mean(word.upper(), P.BY_NAME)}; `regs` lists them")
    return reg


def _unusable(reg: P.Register, action: str) -> ShellError:
    if not reg.supported:
        return ShellError(f"{reg.name} is declared by the original protocol but not implemented")
    return ShellError(f"{reg.name} cannot be {action} (`regs {reg.name}` shows its layout)")


def _parse_values(reg: P.Register, words: Sequence[str]) -> tuple[float | int, ...]:
    """The values of a write of `reg`, checked against the spec exactly as the firmware checks them."""
    if len(words) != len(reg.write):
        expected = " ".join(f.name for f in reg.write)
        raise ShellError(f"{reg.name} takes {len(reg.write)} value{'s' if len(reg.write) > 1 else ''} "
                         f"({expected}), got {len(words)}")
    values: list[float | int] = []
    for field, word in zip(reg.write, words):
        if field.kind == P.F32:
            try:
                values.append(float(word))
            except ValueError:
                raise ShellError(f"{reg.name}.{field.name} must be a number, got {word!r}") from None
            continue
        try:
            value = int(word, 0)
        except ValueError:
            raise ShellError(f"{reg.name}.{field.name} must be an integer, got {word!r}") from None
        # Checked before packing, which would fail with a struct message instead of the spec's range.
        if field.kind == P.U8 and not field.lo <= value <= field.hi:
            raise ShellError(f"{reg.name}.{field.name} = {value} is outside the valid range "
                             f"({field.describe_range()})")
        if field.kind == P.I32 and not _I32_MIN <= value <= _I32_MAX:
            raise ShellError(f"{reg.name}.{field.name} = {value} does not fit a signed 32-bit integer")
        values.append(value)
    try:
        reg.encode(*values)
    except ValueError as exc:
        raise ShellError(str(exc)) from None
    return tuple(values)


def _did_you_mean(word: str, known: Iterable[str]) -> str:
    close = difflib.get_close_matches(word, list(known), n=1)
    return f" (did you mean {close[0]}?)" if close else ""


# ---- formatting ----

def _format_field(reg: P.Register, field: P.Field, value: float | int) -> str:
    if field.kind == P.CHAR:
        text = repr(chr(int(value)))
    elif field.kind == P.F32:
        text = f"{value:.6g}"
    elif field.kind == P.U32:
        text = f"0x{int(value):08x}"
    else:
        text = str(value)
    unit = f" [{field.unit}]" if field.unit else ""
    note = _NOTES.get((reg.addr, field.name))
    return f"{field.name} = {text}{unit}" + (f" ({note(int(value))})" if note else "")


def _register_name(addr: int) -> str:
    reg = P.BY_ADDR[addr]
    return reg.name if reg is not None else "-"


def _modes(modes: Iterable[Mode]) -> str:
    return ",".join(sorted(m.value for m in modes)) or OFF


def _quantity(value: float, unit: str) -> str:
    """A state or command value; NaN (a position before homing) as "unknown"."""
    return f"{value:+.4f} {unit}" if math.isfinite(value) else "unknown"


# Fields whose raw value means something better said in words.
_NOTES: dict[tuple[int, str], Callable[[int], str]] = {
    (P.LASTERROR, "reason"): P.reject_string,
    (P.LASTERROR, "register"): _register_name,
    (P.IDENTITY, "spec_hash"): lambda h: "same spec as this host" if h == P.SPEC_HASH
    else f"differs from this host's 0x{P.SPEC_HASH:08x}",
}


def _direction(reg: P.Register) -> str:
    if not reg.supported:
        return "-"
    return ("R" if reg.readable else "") + ("W" if reg.writable else "")


def _describe_field(field: P.Field, write: bool) -> str:
    parts = [field.name, _KINDS[field.kind]]
    if write:
        parts.append(field.describe_range())
    if field.unit:
        parts.append(f"[{field.unit}]")
    return " ".join(parts)


def _layout(reg: P.Register) -> str:
    if not reg.supported:
        return "declared by the original, not implemented"
    groups = []
    if reg.write:
        groups.append("write: " + ", ".join(_describe_field(f, True) for f in reg.write))
    if reg.read:
        groups.append("read: " + ", ".join(_describe_field(f, False) for f in reg.read))
    return "; ".join(groups)


def _describe_register(reg: P.Register) -> list[str]:
    lines = [f"{reg.name} (0x{reg.addr:02x}, {_direction(reg) or 'none'}): {reg.doc or '-'}"]
    for title, fields, write in (("write", reg.write, True), ("read", reg.read, False)):
        lines += [f"  {title} {_describe_field(f, write)}" for f in fields]
    if reg.blocking:
        lines.append("  blocking: runs in the firmware main loop holding BUSY")
    for title, bits in (("sets", reg.sets), ("clears", reg.clears), ("a 0 value sets", reg.zero_sets)):
        if bits:
            lines.append(f"  {title} {P.describe_flags(bits)} when accepted")
    return lines


def _table(rows: list[list[str]]) -> list[str]:
    """Rows as left-aligned columns two spaces apart."""
    widths = [max(len(row[i]) for row in rows if i < len(row)) for i in range(max(map(len, rows)))]
    return ["  ".join(cell.ljust(width) for cell, width in zip(row, widths)).rstrip() for row in rows]


def _matching(word: str, candidates: Iterable[str]) -> list[str]:
    """Candidates starting with `word`, ignoring case (register names are upper case)."""
    return [c for c in candidates if c.lower().startswith(word.lower())]


def _paths(prefix: str) -> list[str]:
    """Files and directories (with a trailing /) starting with `prefix`."""
    return [p + "/" if os.path.isdir(p) else p for p in sorted(glob.glob(glob.escape(prefix) + "*"))]
