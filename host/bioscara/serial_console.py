"""A joint's serial debug console: its log lines, debug commands and stall-detection trace.

`JointConsole` owns the port (a joint's USB serial, or a simulated joint's pseudo-terminal from
`bioscara sim`). A reader thread splits what the joint prints into lines: a trace sample (the
tab-separated numbers of `firmware.console.debug_commands.TRACE_COLUMNS`) goes to `samples` and to the CSV capture
if one runs; every other line goes to `on_line`, a reject reason or homing outcome the joint logs by
number in words (`in_words`). When the port vanishes (the board reset or was
unplugged), the reader says so, waits for it to come back, reopens it and turns the trace back on
if it was on. The terminal side (prompt, live plot) is in `bioscara.commands.console`.
"""

from __future__ import annotations

import csv
import re
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import serial
from rich.text import Text

from . import trace_plot
from .errors import CommError
from .firmware.spec import protocol as P
from .firmware.console.debug_commands import TRACE_COLUMNS, TRACE_UNITS
from .serial_port import DEFAULT_BAUD, PORT_ERRORS, open_port

CSV_HEADER = ("time_s",) + TRACE_COLUMNS
PLOT_COLUMNS = ("despiked", "filtered", "threshold")  # the stall decision: error against threshold
RETRY_S = 0.2  # how often a vanished port is looked for
_READ_TIMEOUT_S = 0.05  # bounds how long closing the console waits for the reader
_LONGEST_LINE = 4096


@dataclass(frozen=True)
class TraceSample:
    time: float  # s since the console opened, host clock at reception
    values: tuple[float, ...]  # in TRACE_COLUMNS order, units TRACE_UNITS


# The log lines in which a joint names a reject reason or a homing outcome by number (the board
# keeps no texts for them, for its heap): `in_words` puts the protocol's words in.
_CODED = re.compile(r"(rejected a frame for register 0x[0-9a-f]{2}: |homing ended, not homed: )(reason|outcome) (\d+)$")


def in_words(line: str) -> str:
    """A joint's log line with the reject reason or homing outcome it gives by number in words,
    the number after them: "...: reason 4" -> "...: value out of range or not finite (reason 4)"."""
    match = _CODED.search(line)
    if match is None:
        return line
    kind, code = match[2], int(match[3])
    words = P.reject_string(code) if kind == "reason" else P.homing_outcome_string(code)
    return f"{line[:match.start(2)]}{words} ({kind} {code})"


def parse_trace(line: str) -> tuple[float, ...] | None:
    """The values of a trace line, or None if `line` is anything else."""
    fields = line.split("\t")
    if len(fields) != len(TRACE_COLUMNS):
        return None
    try:
        return tuple(float(field) for field in fields)
    except ValueError:
        return None


class TraceCapture:
    """Trace samples to a CSV file: CSV_HEADER, then one row per sample."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._file = self.path.open("w", newline="", encoding="utf-8")
        self._csv = csv.writer(self._file)
        self._csv.writerow(CSV_HEADER)
        self.rows = 0

    def write(self, sample: TraceSample) -> None:
        self._csv.writerow([f"{sample.time:.4f}", *(f"{v:g}" for v in sample.values)])
        self.rows += 1

    def close(self) -> None:
        self._file.close()


class JointConsole:
    """The debug console of the joint on serial port `path`.

    `on_line(text)` gets every line the joint prints that is not a trace sample, plus the
    console's own notices (prefixed "console:"), from the reader thread.
    """

    def __init__(self, path: str, *, on_line: Callable[[str], None], baud: int = DEFAULT_BAUD,
                 keep: int = 3000, retry_s: float = RETRY_S) -> None:
        self.path = path
        self.baud = baud
        self._on_line = on_line
        self._retry_s = retry_s
        self._port: serial.Serial | None = open_port(path, baud=baud, timeout=_READ_TIMEOUT_S)
        self._samples: deque[TraceSample] = deque(maxlen=keep)
        self._capture: TraceCapture | None = None
        self._capture_turned_trace_on = False
        self._tracing = False
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._t0 = time.monotonic()
        self.reconnects = 0
        self.trace_samples = 0
        self.lines_received = 0  # every line from the port, trace samples included
        self._thread = threading.Thread(target=self._read_loop, name=f"console {path}", daemon=True)
        self._thread.start()

    @property
    def connected(self) -> bool:
        return self._port is not None

    def send(self, command: str) -> None:
        """Send one debug command line ("status", "trace on", ...)."""
        words = command.split()
        if len(words) == 2 and words[0] == "trace" and words[1] in ("on", "off"):
            self._tracing = words[1] == "on"
        with self._lock:
            if self._port is None:
                raise CommError(f"{self.path} is not connected (waiting for it to come back)")
            try:
                self._port.write(command.encode() + b"\n")
            except PORT_ERRORS as exc:
                raise CommError(f"cannot send to {self.path}: {exc}") from None

    def samples(self, seconds: float | None = None) -> list[TraceSample]:
        """The trace samples kept, or those of the last `seconds`."""
        with self._lock:
            kept = list(self._samples)
        if seconds is None or not kept:
            return kept
        since = kept[-1].time - seconds
        return [s for s in kept if s.time >= since]

    def start_capture(self, path: str | Path) -> TraceCapture:
        """Capture the trace to a CSV file (turning the trace on); replaces a running capture."""
        capture = TraceCapture(path)
        with self._lock:
            previous, self._capture = self._capture, capture
        if previous is not None:
            previous.close()
        if not self._tracing:
            self.send("trace on")
            self._capture_turned_trace_on = True
        return capture

    def stop_capture(self) -> TraceCapture | None:
        """End the capture (and the trace, if the capture turned it on); returns it, if one ran."""
        with self._lock:
            capture, self._capture = self._capture, None
        if capture is None:
            return None
        capture.close()
        if self._capture_turned_trace_on:
            self._capture_turned_trace_on = False
            try:
                self.send("trace off")
            except CommError:
                pass  # the board is gone; it starts with the trace off anyway
        return capture

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        self.stop_capture()
        with self._lock:
            if self._port is not None:
                self._port.close()
                self._port = None

    def __enter__(self) -> JointConsole:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---- the reader thread ----

    def _read_loop(self) -> None:
        pending = bytearray()
        while not self._stop.is_set():
            port = self._port
            if port is None:
                self._reconnect()
                continue
            try:
                chunk = port.read(port.in_waiting or 1)
            except PORT_ERRORS as exc:
                self._lost(exc)
                pending.clear()
                continue
            pending += chunk
            while (end := pending.find(b"\n")) >= 0 or len(pending) > _LONGEST_LINE:
                end = end if end >= 0 else len(pending)
                line = pending[:end].decode("utf-8", "replace").strip("\r")
                del pending[:end + 1]
                if line:
                    self._dispatch(line)

    def _dispatch(self, line: str) -> None:
        self.lines_received += 1
        values = parse_trace(line)
        if values is None:
            self._on_line(in_words(line))
            return
        sample = TraceSample(time.monotonic() - self._t0, values)
        with self._lock:
            self._samples.append(sample)
            self.trace_samples += 1
            if self._capture is not None:
                self._capture.write(sample)

    def _lost(self, exc: Exception) -> None:
        with self._lock:
            if self._port is not None:
                try:
                    self._port.close()
                except PORT_ERRORS:
                    pass  # already gone with the device
                self._port = None
        self._on_line(f"console: {self.path} lost ({exc}); waiting for it to come back")

    def _reconnect(self) -> None:
        if self._stop.wait(self._retry_s):
            return
        try:
            port = open_port(self.path, baud=self.baud, timeout=_READ_TIMEOUT_S)
        except CommError:
            return  # not back yet
        with self._lock:
            self._port = port
        self.reconnects += 1
        self._on_line(f"console: reconnected to {self.path}")
        if self._tracing:
            try:
                self.send("trace on")  # the board restarted with the trace off
            except CommError:
                pass  # lost again; the next reconnect retries


def plot(samples: Sequence[TraceSample], columns: Sequence[str] = PLOT_COLUMNS, *, width: int = 80,
         height: int = 16, title: str = "") -> Text:
    """The trace columns `columns` of `samples` as a terminal chart (one y axis: pick same units)."""
    unknown = [c for c in columns if c not in TRACE_COLUMNS]
    if unknown:
        raise ValueError(f"no trace column {', '.join(unknown)}; the columns are {' '.join(TRACE_COLUMNS)}")
    indexes = [TRACE_COLUMNS.index(c) for c in columns]
    units = sorted({TRACE_UNITS[i] for i in indexes if TRACE_UNITS[i]})
    span = samples[-1].time - samples[0].time if samples else 0.0
    heading = title or f"trace: {len(samples)} samples over {span:.1f} s"
    series = {c: [s.values[i] for s in samples] for c, i in zip(columns, indexes)}
    return trace_plot.render(series, width=width, height=height,
                             title=f"{heading}  [{', '.join(units)}]" if units else heading)
