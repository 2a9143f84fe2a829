"""Littlefs images of the emulated Pico's filesystem, made from exactly the files `bioscara flash` deploys.

`joint_image("J1")` is what `bioscara flash <port> --joint J1` leaves on a stock MicroPython v1.28.0
Pico (the same `bioscara.firmware_flash.build_image`, for the board that probe reports), so a test can boot a
deployed joint without the ~30 s flash step.
"""

from __future__ import annotations

from pathlib import Path

from littlefs import LittleFS

from bioscara import firmware_flash
from bioscara.mpboard import BoardInfo

# MicroPython v1.28.0 RPI_PICO (ports/rp2 _boot.py and its flash layout): littlefs v2 at flash
# offset 0xA0000, 352 blocks of 4096 bytes, program size 256.
BLOCK_SIZE = 4096
BLOCK_COUNT = 352
PROG_SIZE = 256

# What mpboard's PROBE reports on the stock UF2 (tests/chip checks it against the emulated board).
STOCK_PICO = BoardInfo(implementation="micropython", version=(1, 28, 0), mpy=4870, small_int_bits=31,
                       platform="rp2", machine="Raspberry Pi Pico with RP2040", i2c_target=True)


def littlefs_image(files: dict[str, bytes]) -> bytes:
    """A littlefs image holding `files` (absolute board path -> content), as MicroPython mounts it."""
    fs = LittleFS(block_size=BLOCK_SIZE, block_count=BLOCK_COUNT, prog_size=PROG_SIZE, read_size=32,
                  lookahead_size=32)
    for path, data in files.items():
        parent = path.rsplit("/", 1)[0]
        if parent:
            fs.makedirs(parent, exist_ok=True)
        with fs.open(path, "wb") as f:
            f.write(data)
    return bytes(fs.context.buffer)


def read_image(image: bytes) -> dict[str, bytes]:
    """Every file in a littlefs image of the Pico's filesystem: absolute path -> content."""
    fs = LittleFS(block_size=BLOCK_SIZE, block_count=BLOCK_COUNT, prog_size=PROG_SIZE, read_size=32,
                  lookahead_size=32, mount=False)
    fs.context.buffer[:] = image
    fs.mount()
    found: dict[str, bytes] = {}
    for root, _dirs, names in fs.walk("/"):
        for name in names:
            path = f"{root.rstrip('/')}/{name}"
            with fs.open(path, "rb") as f:
                found[path] = f.read()
    return found


def joint_files(joint: str, board: BoardInfo = STOCK_PICO) -> dict[str, bytes]:
    """The files `bioscara flash` deploys for `joint` on `board` (board path -> content)."""
    return firmware_flash.build_image(joint, board).files


def joint_image(joint: str, path: Path | None = None) -> bytes:
    """The filesystem of a stock Pico after `bioscara flash --joint <joint>`; written to `path` if given."""
    image = littlefs_image(joint_files(joint))
    if path is not None:
        path.write_bytes(image)
    return image
