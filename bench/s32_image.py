"""Flash and RAM figures of the uStepper S32 image (`make bench-s32`, after `make s32-image`).

    python bench/s32_image.py build/s32

Prints `name value` lines, from the built files (the ELF's symbols, arm-none-eabi-nm):

    s32.flash_used_kb             firmware.bin, the frozen joint firmware included
    s32.flash_free_kb             what is left of the 252 KB the linker gives the image (the last
                                  4 KB of the 256 KB hold the joint's configuration)
    s32.frozen_kb                 the frozen modules' share: the symbols mpy-tool names (bytecode,
                                  machine code, constants, their qstrs)
    s32.static_ram_kb             .data + .bss
    s32.gc_heap_kb                the GC heap's size (_heap_end - _heap_start)

    s32.heap_free_after_boot_kb   what the firmware logs once booted as J1 (gc.mem_free() after a
                                  collection, before the main loop), on the image booted in Qiling
                                  (tests/s32_emu.py, `make s32-emu`) with the TMC5130 and TLE5012B
                                  models; without Qiling, or when the emulation fails, it says
                                  why it is not measured instead of printing a figure

Exit status 1 when the image is not there (with what is missing).
"""

from __future__ import annotations

import pathlib
import re
import shutil
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
EMULATOR_PYTHON = ROOT / "build" / "qiling-venv" / "bin" / "python"
FLASH_FOR_IMAGE = 252 * 1024  # firmware/boards/USTEPPER_S32/ustepper_s32.ld: FLASH
TARGET_FLASH_FREE_KB = 4.0
TARGET_HEAP_FREE_KB = 12.0


def symbols(elf: pathlib.Path) -> dict[str, int]:
    out = subprocess.run(["arm-none-eabi-nm", str(elf)], capture_output=True, text=True, check=True).stdout
    found = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 3:
            found[parts[2]] = int(parts[0], 16)
    return found


# Prefixes of what tools/mpy-tool.py emits for frozen modules (LTO hides the object file's share).
FROZEN = re.compile(r"(fun_data_|proto_fun_|raw_code_|const_obj_|const_qstr_table_data_|const_table_data_|children_|"
                    r"frozen_module_|mp_frozen_|mp_qstr_frozen_const_)")


def frozen_bytes(elf: pathlib.Path) -> int:
    out = subprocess.run(["arm-none-eabi-nm", "-S", str(elf)], capture_output=True, text=True, check=True).stdout
    return sum(int(parts[1], 16) for parts in (line.split() for line in out.splitlines())
               if len(parts) == 4 and FROZEN.match(parts[3]))


def main(build: pathlib.Path) -> int:
    binary, elf = build / "firmware.bin", build / "firmware.elf"
    missing = [p for p in (binary, elf) if not p.exists()]
    if missing:
        print(f"no S32 image: {', '.join(map(str, missing))} missing (make s32-image builds it)", file=sys.stderr)
        return 1
    if shutil.which("arm-none-eabi-nm") is None:
        print("arm-none-eabi-nm is missing (apt-get install binutils-arm-none-eabi)", file=sys.stderr)
        return 1
    sym = symbols(elf)
    used = binary.stat().st_size
    print(f"s32.flash_used_kb {used / 1024:.1f}")
    print(f"s32.flash_free_kb {(FLASH_FOR_IMAGE - used) / 1024:.1f}")
    print(f"s32.frozen_kb {frozen_bytes(elf) / 1024:.1f}")
    print(f"s32.static_ram_kb {(sym['_ebss'] - sym['_ram_start']) / 1024:.1f}")
    print(f"s32.gc_heap_kb {(sym['_heap_end'] - sym['_heap_start']) / 1024:.1f}")
    heap, why = heap_after_boot(binary)
    if heap is None:
        print(f"s32.heap_free_after_boot_kb: not measured ({why}); the GC heap's size above is its upper bound",
              file=sys.stderr)
    else:
        print(heap)
    print(f"targets: flash free >= {TARGET_FLASH_FREE_KB:g} KB, heap free after boot >= {TARGET_HEAP_FREE_KB:g} KB",
          file=sys.stderr)
    return 0


def heap_after_boot(binary: pathlib.Path) -> tuple[str | None, str]:
    """The emulator's `s32.heap_free_after_boot_kb` line for J1's flash, or None and why not."""
    if not EMULATOR_PYTHON.exists():
        return None, "Qiling is missing: make s32-emu"
    from bioscara import s32flash

    flash = binary.parent / "flash_j1.bin"
    flash.write_bytes(s32flash.build("J1", binary).composed())
    result = subprocess.run([str(EMULATOR_PYTHON), str(ROOT / "tests" / "s32_emu.py"), str(flash)],
                            capture_output=True, text=True, timeout=1800, check=False)
    if result.returncode != 0:
        last = [line for line in result.stderr.splitlines() if line.strip()][-1:] or ["no output"]
        return None, f"the emulated S32 did not report it: {last[0][:160]}"
    return result.stdout.strip(), ""


if __name__ == "__main__":
    sys.exit(main(pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else "build/s32")))
