"""Flash a uStepper S32 joint: the MicroPython image (`make s32-image`) and the joint's
configuration, through the STM32F401's ROM DFU bootloader with `dfu-util` (docs/s32.md).

The S32 has no filesystem: its firmware is frozen into the image, and the joint's JSON
configuration sits in the last 4 KB of flash (CONFIG_ADDRESS; firmware/joint/s32/board.py reads it
at boot, the board's linker script keeps code out). One download writes both: the image, padded
with erased bytes (0xFF) up to CONFIG_ADDRESS, then the configuration and a 0xFF terminator. The
configuration is then read back from flash with dfu-util's upload and compared (the joint's name
and address are in it), and the upload's `leave` starts the new firmware. With `--bus` the CLI
then asks the running joint for its identity over I2C (firmware_flash.check_identity).
"""

from __future__ import annotations

import json
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

from .firmware.config import schema as firmware_config
from .firmware_flash import joint_config
from .mpboard import FlashError
from .errors import ConfigError

FLASH_START = 0x08000000
CONFIG_ADDRESS = 0x0803F000  # firmware/joint/s32/board.py CONFIG_ADDRESS
CONFIG_SIZE = 4096
IMAGE_LIMIT = CONFIG_ADDRESS - FLASH_START  # 252 KB
DEFAULT_IMAGE = Path("build/s32/firmware.bin")
# dfu-util's exit status when no DFU device answers, and what it prints then
_NO_DEVICE = "No DFU capable USB device available"


def s32_config(joint: str, user: tuple[bytes, firmware_config.JointConfig] | None = None) -> bytes:
    """The configuration an S32 joint boots with: the user's (which must say backend "s32"), else
    the shipped one of `joint` with the S32's motor and bus (the Pico's pins mean nothing there).
    Validated as the firmware validates it; compact JSON."""
    if user is not None:
        text, cfg = user
        data = json.loads(text.decode("utf-8"))
    else:
        text, cfg = joint_config(joint)
        data = json.loads(text.decode("utf-8"))
        data["motor"] = {"backend": "s32"}
        data["i2c"] = {"bus": firmware_config.S32_JOINT_BUS}
    checked = firmware_config.parse(data, f"{joint.lower()} for the S32")
    if checked.motor.get("backend") != "s32":
        raise ConfigError(f"{checked.source}: motor.backend must be \"s32\" on a uStepper S32")
    if not checked.valid:
        raise ConfigError("\n".join(checked.errors))
    raw = json.dumps(data, separators=(",", ":"), sort_keys=True).encode("utf-8")
    if len(raw) >= CONFIG_SIZE:
        raise ConfigError(f"the configuration is {len(raw)} bytes; the S32 keeps at most {CONFIG_SIZE - 1}")
    return raw


@dataclass(frozen=True)
class S32Image:
    joint: str
    address: int
    firmware: Path
    firmware_bytes: int
    config: bytes

    def composed(self) -> bytes:
        """What one DFU download writes from FLASH_START: image, erased padding, configuration."""
        data = self.firmware.read_bytes()
        return data + b"\xff" * (IMAGE_LIMIT - len(data)) + self.config + b"\xff"


def build(joint: str, image: Path = DEFAULT_IMAGE,
          user: tuple[bytes, firmware_config.JointConfig] | None = None) -> S32Image:
    """Check the image and the configuration before any device is touched."""
    if not image.is_file():
        raise FlashError(f"no S32 image at {image}: build it with `make s32-image` (docs/s32.md) or give --image")
    size = image.stat().st_size
    if size > IMAGE_LIMIT:
        raise FlashError(f"{image} is {size} bytes: an S32 image must fit {IMAGE_LIMIT} bytes "
                         f"(the last {CONFIG_SIZE} of the 256 KB hold the joint's configuration)")
    if image.read_bytes()[:4] == b"DfuS":
        raise FlashError(f"{image} is a .dfu file: give the firmware.bin beside it")
    config = s32_config(joint, user)
    address = json.loads(config)["address"]
    return S32Image(joint, address, image, size, config)


def dfu_util() -> str:
    found = shutil.which("dfu-util")
    if found is None:
        raise FlashError("dfu-util is not installed (Debian: apt-get install dfu-util)")
    return found


def commands(image: S32Image, download: Path, readback: Path) -> list[list[str]]:
    """The two dfu-util runs: download everything (alt 0 = internal flash), then upload the
    configuration back and leave DFU mode (the new firmware starts)."""
    tool = dfu_util()
    return [
        [tool, "-a", "0", "-s", f"0x{FLASH_START:08x}", "-D", str(download)],
        [tool, "-a", "0", "-s", f"0x{CONFIG_ADDRESS:08x}:{len(image.config) + 1}:leave", "-U", str(readback)],
    ]


def _run(argv: list[str], what: str) -> None:
    try:
        result = subprocess.run(argv, capture_output=True, text=True, timeout=300, check=False)
    except subprocess.TimeoutExpired:
        raise FlashError(f"dfu-util did not finish {what} within 300 s") from None
    if result.returncode != 0:
        out = (result.stderr + result.stdout).strip()
        if _NO_DEVICE in out:
            raise FlashError("no S32 in DFU mode: hold BOOT0 high while resetting (or powering) the board, "
                             "check the USB cable, then flash again")
        last = out.splitlines()[-1] if out else f"exit status {result.returncode}"
        raise FlashError(f"dfu-util failed {what}: {last}")


def write(image: S32Image) -> None:
    """Download, read the configuration back, compare; FlashError on any difference."""
    with tempfile.TemporaryDirectory(prefix="bioscara-s32-") as tmp:
        download, readback = Path(tmp) / "s32.bin", Path(tmp) / "config.bin"
        download.write_bytes(image.composed())
        first, second = commands(image, download, readback)
        _run(first, "writing the image")
        _run(second, "reading the configuration back")
        got = readback.read_bytes() if readback.exists() else b""
    if got != image.config + b"\xff":
        raise FlashError(f"verification failed: the configuration read back from 0x{CONFIG_ADDRESS:08x} "
                         f"is not the one written ({len(got)} bytes); flash again")
