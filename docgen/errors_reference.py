"""Every error a user can meet, collected from the code: the original error codes and the
exception classes (bioscara.errors), the joint's reject reasons and v2 verdicts (the spec), and
each message the host raises (its `raise ...Error(...)` sites, read with `ast`)."""

from __future__ import annotations

import ast
import inspect
from dataclasses import dataclass
from pathlib import Path

from bioscara import cli, errors
from bioscara.firmware.spec import protocol as P
from bioscara.firmware.spec import protocol_v2 as V

HOST = Path(errors.__file__).resolve().parent
_EXIT = {"ConfigError": cli.USAGE, "InvalidArgumentError": cli.USAGE}


@dataclass(frozen=True)
class Raise:
    """One `raise SomeError(message)` in the host package; `message` has `…` for what varies."""

    error: str
    message: str
    module: str


def _template(node: ast.expr) -> str | None:
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value
    if isinstance(node, ast.JoinedStr):
        return "".join(part.value if isinstance(part, ast.Constant) else "…" for part in node.values)
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add):
        left, right = _template(node.left), _template(node.right)
        return None if left is None and right is None else (left or "…") + (right or "…")
    return None


def raises() -> list[Raise]:
    """The host's raise sites of bioscara.errors classes, with a literal (or f-string) message."""
    names = {name for name, cls in inspect.getmembers(errors, inspect.isclass) if issubclass(cls, errors.BioscaraError)}
    found = []
    for path in sorted(HOST.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if not (isinstance(node, ast.Raise) and isinstance(node.exc, ast.Call)):
                continue
            func = node.exc.func
            name = func.id if isinstance(func, ast.Name) else getattr(func, "attr", None)
            if name in names and node.exc.args:
                message = _template(node.exc.args[0])
                if message and sum(c.isalpha() for c in message) >= 3:
                    found.append(Raise(name, " ".join(message.split()), str(path.relative_to(HOST.parent))))
    return sorted(set(found), key=lambda r: (r.error, r.message))


def exceptions() -> str:
    """Each exception class: its original error code and message, and the CLI's exit status."""
    out = ["| exception | code | the message ends with | `bioscara` exit status |", "|---|---|---|---|"]
    classes = [errors.BioscaraError, *errors.BioscaraError.__subclasses__()]
    for cls in classes:
        code = cls.code
        status = _EXIT.get(cls.__name__, cli.DEVICE)
        out.append(f"| `{cls.__name__}` | {code.value} `{code.name}` | `[{code.name}: {P.error_string(code)}]` | {status} |")
    return "\n".join(out) + "\n"


def messages() -> str:
    """The catalogue of host messages, grouped by exception."""
    out = []
    current = None
    for r in raises():
        if r.error != current:
            current = r.error
            out += ["", f"### `{current}`", "", "| message (`…`: filled in) | raised in |", "|---|---|"]
        text = r.message.replace("|", "\\|").replace("`", "'")
        out.append(f"| {text} | `{r.module}` |")
    return "\n".join(out).lstrip("\n") + "\n"


def _causes(table: tuple[tuple[int, str], ...], notes: dict[int, tuple[str, str]], what: str) -> str:
    out = ["| | message | cause | fix |", "|---|---|---|---|"]
    for value, text in table:
        if value not in notes:
            raise ValueError(f"{what} {value} ({text!r}) has no cause and fix in docs/troubleshooting.md's generator "
                             f"(docgen/errors_reference.py)")
        cause, fix = notes[value]
        out.append(f"| {value} | {text} | {cause} | {fix} |")
    return "\n".join(out) + "\n"


REJECT_NOTES = {
    P.REJECT_NONE: ("no frame was rejected", "–"),
    P.REJECT_UNKNOWN_REGISTER: ("a raw frame (`shell --expert`, another host) named a register the spec does not have",
                                "`bioscara shell` then `regs` lists the registers"),
    P.REJECT_UNSUPPORTED: ("the original declared the register but neither side implements it",
                           "use the register the table marks as its replacement; the original host never sends these"),
    P.REJECT_LENGTH: ("a payload of the wrong size: a host built for another spec, or a damaged frame",
                      "`bioscara info JOINT` compares the spec hash with this host's; flash matching firmware"),
    P.REJECT_VALUE: ("a value outside the register's range, NaN or infinite", "the register table gives each range"),
    P.REJECT_BUSY: ("a blocking command (HOME, CHECKORIENTATION) is running", "wait for BUSY to clear, or send STOP"),
    P.REJECT_QUEUE_FULL: ("commands arrived faster than the main loop applies them",
                          "send fewer commands per cycle; `bioscara console PORT -c status` shows the loop rate"),
    P.REJECT_DISABLED: ("the joint's configuration is invalid or its motor backend failed at boot: it stays on the bus, disabled",
                        "`bioscara console PORT -c status` says why; fix `/joint_config.json` (`bioscara flash PORT --show-config`)"),
    P.REJECT_NOT_ENABLED: ("a motion command while NOTENABLED (the original applied it)",
                           "`bioscara enable JOINT` (SETUP) first"),
    P.REJECT_STALLED: ("a motion command while STALL is set", "find what blocked the joint, then `bioscara enable JOINT` re-arms it"),
    P.REJECT_HOMING_SENSITIVITY: ("HOME's sensitivity is within the joint's free-running PID error: it would home on noise",
                                  "raise `homing.sensitivity` in the arm configuration"),
}

VERDICT_NOTES = {
    V.REASON_OK: ("the frame was applied", "–"),
    V.REASON_CRC: ("a bit flipped on the wire (noise, a long bus, clock stretching on a Pi 1-3)",
                   "the host retransmits; many in `bioscara info` mean wiring: see Hardware"),
    V.REASON_SEQUENCE: ("a stale or replayed frame, or two v2 hosts on one joint",
                        "one v2 host per joint; a second program uses `--protocol legacy`"),
    V.REASON_FRAME: ("a write cut short or with a byte slipped in", "as for CRC"),
    V.REASON_COMMAND: ("the mailbox named no writable register of at most 4 payload bytes", "send such a command in legacy"),
    V.REASON_VALUE: ("the legacy register's own check refused the value", "as LASTERROR 4 and 10"),
    V.REASON_BUSY: ("a blocking command is running, or the queue is full", "as LASTERROR 5 and 6"),
    V.REASON_DISABLED: ("the joint is disabled, not enabled or stalled; its status flags say which", "as LASTERROR 7-9"),
}


def reject_reasons() -> str:
    return _causes(P.REJECT_REASONS, REJECT_NOTES, "reject reason")


def verdicts() -> str:
    return _causes(V.REASONS, VERDICT_NOTES, "v2 verdict")
