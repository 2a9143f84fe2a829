"""Monitor recordings: CSV or JSON Lines (by file suffix), stamped with the protocol spec hash.

Rows are flushed as they are written, so a recording interrupted by a crash keeps every row
before it (a JSON Lines row cut short by the kill is skipped with a warning when read). The first line is metadata: in CSV a `# {json}` comment, in JSON Lines `{"meta": {...}}`.
"""

from __future__ import annotations

import csv
import datetime
import json
import logging
import math
from pathlib import Path
from typing import IO, Any

from . import __version__
from .communicator import Snapshot
from .errors import InvalidArgumentError
from .firmware.spec import protocol as P

SUFFIXES = (".csv", ".jsonl", ".ndjson")
log = logging.getLogger("bioscara.recording")


def _kind(path: Path) -> str:
    if path.suffix not in SUFFIXES:
        raise InvalidArgumentError(f"{path}: record to a .csv or .jsonl file")
    return "csv" if path.suffix == ".csv" else "jsonl"


class TraceWriter:
    def __init__(self, path: str | Path, joints: list[str], rate_hz: float, bus: str,
                 units: dict[str, str] | None = None) -> None:
        """`units`: each joint's position unit (rad or m), kept in the metadata for `plot`."""
        self.path = Path(path)
        self.kind = _kind(self.path)
        self.columns = ["time", "cycle"] + [f"{j}/{v}" for j in joints for v in ("position", "velocity",
                                                                                 "flags", "home")] + ["fault"]
        self.meta = {"bioscara": __version__, "spec_hash": f"{P.SPEC_HASH:08x}", "protocol": P.PROTOCOL_VERSION,
                     "rate_hz": rate_hz, "bus": bus, "joints": joints, "units": units or {},
                     "started": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}
        try:
            self._file: IO[str] = open(self.path, "w", newline="")
        except OSError as exc:
            raise InvalidArgumentError(f"cannot write the recording {self.path}: {exc.strerror or exc}") from None
        self.rows = 0
        if self.kind == "csv":
            self._file.write("# " + json.dumps(self.meta) + "\n")
            self._csv = csv.writer(self._file)
            self._csv.writerow(self.columns)
        else:
            self._file.write(json.dumps({"meta": self.meta}) + "\n")
        self._file.flush()

    def write(self, snapshot: Snapshot) -> None:
        values = snapshot.values()
        if self.kind == "csv":
            row: list[Any] = [f"{snapshot.time:.6f}", snapshot.cycle]
            row += [_cell(values[c]) for c in self.columns[2:-1]]
            self._csv.writerow(row + [snapshot.fault or ""])
        else:
            clean = {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in values.items()}
            self._file.write(json.dumps({"time": snapshot.time, "cycle": snapshot.cycle, "values": clean,
                                         "fault": snapshot.fault}) + "\n")
        self._file.flush()
        self.rows += 1

    def close(self) -> None:
        self._file.close()


def _cell(value: float) -> str:
    return "" if isinstance(value, float) and math.isnan(value) else str(value)


def read_trace(path: str | Path) -> tuple[dict[str, Any], list[dict[str, float | None]]]:
    """Metadata and rows (column name -> value, None where empty) of a recording."""
    path = Path(path)
    kind = _kind(path)
    try:
        with open(path, newline="") as f:
            first = f.readline()
            if kind == "csv":
                if not first.startswith("# "):
                    raise ValueError("missing the '# {metadata}' first line")
                meta = json.loads(first[2:])
                rows = [{k: (float(v) if v not in ("", None) and k != "fault" else (v or None))
                         for k, v in row.items()} for row in csv.DictReader(f)]
            else:
                meta = json.loads(first)["meta"]
                rows = []
                for line in f:
                    try:
                        record = json.loads(line)
                    except ValueError:
                        if line.endswith("\n"):
                            raise
                        log.warning("%s: skipped the last line, cut short (the recording was interrupted)", path)
                        break
                    rows.append({"time": record["time"], "cycle": record["cycle"], **record["values"]})
        for key in ("joints", "bus", "spec_hash", "rate_hz"):
            meta[key]  # noqa: B018 - a recording without these cannot be labelled or plotted
        if not isinstance(meta["joints"], list):
            raise ValueError("metadata 'joints' is not a list")
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise InvalidArgumentError(f"{path}: not a bioscara recording ({type(exc).__name__}: {exc})") from None
    return meta, rows
