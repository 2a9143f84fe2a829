"""The built uStepper S32 image (`make s32-image`): it fits with the flash the issue asks to keep
free, and it froze exactly the files the S32 manifest declares (boards/s32.py) plus its main."""

from __future__ import annotations

import pathlib
import shutil
import subprocess

import pytest

from bioscara import firmware_flash, s32flash

ROOT = pathlib.Path(__file__).resolve().parents[1]
BUILD = ROOT / "build" / "s32"


def _image() -> pathlib.Path:
    if not (BUILD / "firmware.elf").exists():
        pytest.skip("build/s32/firmware.elf is missing: make s32-image builds it (it needs "
                    "../shared/stm32/micropython-v1.28.0-stm32-src.tar.xz and arm-none-eabi-gcc)")
    if shutil.which("arm-none-eabi-nm") is None:
        pytest.skip("arm-none-eabi-nm is missing (apt-get install binutils-arm-none-eabi)")
    return BUILD


def test_the_image_leaves_4_kb_of_flash_free():
    build = _image()
    assert s32flash.IMAGE_LIMIT - (build / "firmware.bin").stat().st_size >= 4096


def test_the_image_froze_what_the_s32_manifest_declares():
    build = _image()
    out = subprocess.run(["arm-none-eabi-nm", str(build / "firmware.elf")], capture_output=True, text=True,
                         check=True).stdout
    frozen = {line.split()[-1][len("frozen_module_"):] for line in out.splitlines() if " frozen_module_" in line}
    expected = {"main"} | {"joint_" + name[:-3].replace("/", "_") for name in firmware_flash.board_files("s32")
                           if name != "s32/main.py"}
    assert frozen == expected
