"""Firmware and host load the identical protocol table: the same file, the same hash on both interpreters."""

from __future__ import annotations

import os
import pathlib
import shutil
import subprocess
import sys

import bioscara.firmware.spec.protocol as host_protocol

ROOT = pathlib.Path(__file__).resolve().parents[1]

DUMP = """
from joint.spec import protocol as P
print(P.SPEC_HASH)
for r in P.REGISTERS:
    print(r.addr, r.name, r.supported, r.blocking, r.sets, r.clears, r.zero_sets, r.wfmt, r.rfmt,
          [(f.name, f.unit, f.lo, f.hi) for f in r.write], [(f.name, f.unit) for f in r.read])
"""


def _host_dump() -> str:
    namespace: dict[str, object] = {}
    lines: list[str] = []
    namespace["print"] = lambda *args: lines.append(" ".join(str(a) for a in args))
    exec(DUMP.replace("from joint.spec import protocol as P", "import bioscara.firmware.spec.protocol as P"), namespace)
    return "\n".join(lines)


def test_the_host_imports_the_firmware_file_itself() -> None:
    assert pathlib.Path(host_protocol.__file__).resolve() == ROOT / "firmware" / "joint" / "spec" / "protocol.py"


def test_micropython_and_cpython_see_the_same_table_and_hash() -> None:
    binary = shutil.which("micropython") or str(pathlib.Path(sys.executable).parent / "micropython")
    env = dict(os.environ, MICROPYPATH=str(ROOT / "firmware"))
    result = subprocess.run([binary, "-c", DUMP], capture_output=True, text=True, env=env, check=True)
    mp = result.stdout.strip().splitlines()
    host = _host_dump().splitlines()
    assert mp[0] == host[0] == str(host_protocol.SPEC_HASH)
    assert len(mp) == len(host) == len(host_protocol.REGISTERS) + 1
    for a, b in zip(mp[1:], host[1:]):
        assert a.split()[:9] == b.split()[:9]
