"""`bioscara ports [PATH...]`: the serial ports, and which are HIL bridges, joint debug ports,
MicroPython or CircuitPython boards (pyserial's list_ports and the USB ids, then a short probe of
each candidate)."""

from __future__ import annotations

import argparse
import re
import time
from typing import Any

from rich.table import Table

from ..errors import BioscaraError
from ..session import Session

NAME = "ports"
HELP = ("list the serial ports and say which are HIL bridges (--bus serial:PORT), joint debug ports "
        "(bioscara console PORT), MicroPython boards (bioscara flash PORT) or CircuitPython boards "
        "(bioscara flash --runtime circuitpython --drive DIR)")
EXAMPLES = (
    ('bioscara ports', 'the serial ports and what each is'),
    ('bioscara ports /dev/pts/7', 'also probe a pseudo-terminal (from `bioscara sim`)'),
)
USES = ("json",)
# USB vendor ids of boards that run MicroPython: Raspberry Pi (Pico), MicroPython's own.
MICROPYTHON_VIDS = {0x2E8A: "Raspberry Pi", 0xF055: "MicroPython"}
# CircuitPython presents every board under Adafruit's vendor id (the Pico: 239a:80f4), and names
# its serial interface "CircuitPython CDC control"; MicroPython's Pico is 2e8a:0005.
CIRCUITPYTHON_VID = 0x239A
FLASH_CIRCUITPYTHON = "bioscara flash --runtime circuitpython --drive /path/to/CIRCUITPY --joint j1"


def runtime_of(vid: int | None, pid: int | None, product: str | None, interface: str | None) -> str | None:
    """"circuitpython", "micropython" or None (unknown) from a port's USB identity."""
    names = f"{product or ''} {interface or ''}"
    if vid == CIRCUITPYTHON_VID or "CircuitPython" in names:
        return "circuitpython"
    if vid in MICROPYTHON_VIDS or "MicroPython" in names:
        return "micropython"
    return None
_STATUS = re.compile(r"\b(J[1-4]) at 0x([0-9a-f]{2})")
# Longest wait for a joint's status line or a REPL's prompt. A board answers in milliseconds, but a
# busy one (a joint homing, a loaded host, an emulated board) can take far longer; the wait ends as
# soon as the answer is complete, so only a port nothing answers on costs all of it.
ANSWER_WAIT_S = 3.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("paths", nargs="*", metavar="PATH", help="also probe these ports (e.g. a pseudo-terminal "
                        "from `bioscara sim`); with none given, every USB serial port is listed")
    parser.add_argument("--no-probe", action="store_true",
                        help="only list: send nothing (a probe writes a bridge VERSION request and a `status` line)")


def probe(path: str) -> dict[str, Any]:
    """What answers on `path`: a HIL bridge, a joint's debug console, a MicroPython REPL."""
    from ..bus.serial import SerialBus
    from ..serial_port import open_port

    try:
        bus = SerialBus(path, timeout=0.1, attempts=1)
    except BioscaraError as exc:
        if "busy" in exc.detail or "does not exist" in exc.detail or "permission" in exc.detail:
            return {"kind": "unavailable", "detail": exc.detail}
    else:
        version = bus.version
        bus.close()
        return {"kind": "HIL bridge", "detail": f"framing protocol {version.protocol}, firmware "
                f"{'.'.join(map(str, version.firmware))}, I2C {version.i2c_hz // 1000} kHz",
                "use": f"--bus serial:{path}"}
    try:
        port = open_port(path, timeout=0.05)
    except BioscaraError as exc:
        return {"kind": "unavailable", "detail": exc.detail}
    try:
        port.reset_input_buffer()
        port.write(b"\r\nstatus\r\n")
        seen = b""
        deadline = time.monotonic() + ANSWER_WAIT_S
        while True:  # read before looking at the clock: a host held up meanwhile still sees the answer
            seen += port.read(256)
            if _answered(seen) or time.monotonic() >= deadline:
                break
    except OSError as exc:
        return {"kind": "unavailable", "detail": str(exc)}
    finally:
        port.close()
    text = seen.decode("utf-8", "replace")
    found = _STATUS.search(text)
    if found:
        return {"kind": "joint debug port", "detail": f"{found.group(1).lower()} at 0x{found.group(2)}",
                "use": f"bioscara console {path}"}
    if "CircuitPython" in text:
        return {"kind": "CircuitPython board", "detail": "REPL (no joint firmware running)",
                "use": FLASH_CIRCUITPYTHON}
    if ">>>" in text or "Traceback" in text or "MicroPython" in text:
        return {"kind": "MicroPython board", "detail": "REPL (no joint firmware running)",
                "use": f"bioscara flash {path} --joint j1"}
    return {"kind": "unknown", "detail": "neither a bridge, a joint nor a REPL answered"}


def _answered(seen: bytes) -> bool:
    """A complete answer to `status`: the joint's status line, or the REPL's traceback and prompt."""
    if b"\n" in seen.partition(b"at 0x")[2]:
        return True
    return b"Traceback" in seen and seen.rstrip().endswith(b">>>")


def run(args: argparse.Namespace, session: Session) -> int:
    from serial.tools import list_ports

    entries: list[dict[str, Any]] = []
    listed = {info.device: info for info in list_ports.comports()}
    for device, info in sorted(listed.items()):
        if info.vid is None and device not in args.paths:
            continue  # legacy UARTs without a USB identity (ttyS*): not a board
        runtime = runtime_of(info.vid, info.pid, info.product, info.interface)
        entry: dict[str, Any] = {"port": device, "usb": f"{info.vid:04x}:{info.pid:04x}" if info.vid else None,
                                 "description": info.description, "micropython_vendor": runtime == "micropython",
                                 "runtime": runtime}
        if runtime is not None and not args.no_probe:
            entry.update(probe(device))
            if runtime == "circuitpython" and entry["kind"] == "MicroPython board":
                # A REPL prompt without the banner: the USB identity tells the runtime.
                entry.update(kind="CircuitPython board", use=FLASH_CIRCUITPYTHON)
        elif runtime == "circuitpython":
            entry.update(kind="CircuitPython board", detail="CircuitPython USB id (not probed)",
                         use=FLASH_CIRCUITPYTHON)
        elif runtime is not None:
            entry.update(kind="MicroPython board",
                         detail=f"{MICROPYTHON_VIDS.get(info.vid or -1, 'MicroPython')} USB id (not probed)")
        else:
            entry.update(kind="serial port", detail=info.description or "")
        entries.append(entry)
    for path in args.paths:
        if path not in listed:
            entry = {"port": path, "usb": None, "description": "", "micropython_vendor": False, "runtime": None}
            entry.update(probe(path) if not args.no_probe else {"kind": "serial port", "detail": "not probed"})
            entries.append(entry)
    table = Table("port", "is", "detail", "use with", box=None)
    for e in entries:
        table.add_row(e["port"], e["kind"], e.get("detail", ""), e.get("use", ""))
    session.emit(entries, table if entries else "no USB serial ports (is the board plugged in?)")
    return 0
