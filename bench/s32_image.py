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
                                  through the host's Bus over it (tests/s32_bus.py, `make s32-emu`)

and estimates from instructions counted there (one instruction taken as one cycle of the 84 MHz
core; the emulator has no timing fidelity, real code takes more cycles than instructions):

    s32.main_loop_instructions_estimate          per main-loop iteration (interrupts included),
                                                 no host on the bus
    s32.main_loop_instructions_v2_estimate       the same while serving v2 to the host's V2Link
                                                 cycling at 100 Hz
    s32.i2c_legacy_read_instructions_estimate    in I2C1's interrupts over a legacy IDENTITY read
                                                 (the Python IRQ handler included)
    s32.i2c_v2_cycle_instructions_estimate       in I2C1's interrupts over one v2 cycle of the
                                                 host's V2Link (mem mode: C only)

Without Qiling, or when the emulation fails, it says why they are not measured instead.

Exit status 1 when the image is not there (with what is missing).
"""

from __future__ import annotations

import pathlib
import re
import shutil
import subprocess
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parents[1]
HEAP_LINE = re.compile(r"booted: (\d+) bytes of heap free")
J1_ADDRESS = 0x11
ESTIMATE_MS = 20  # of the main loop counted instruction by instruction
V2_CYCLES = 5  # of the host's V2Link, one every V2_PERIOD_S, while the main loop is counted
V2_PERIOD_S = 0.01
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
    lines, why = emulated_figures()
    if not lines:
        print(f"s32.heap_free_after_boot_kb and the instruction estimates: not measured ({why}); the GC heap's "
              "size above is the heap's upper bound", file=sys.stderr)
    for line in lines[:-1]:
        print(line, flush=True)
    if lines:
        print(lines[-1], file=sys.stderr)
    print(f"targets: flash free >= {TARGET_FLASH_FREE_KB:g} KB, heap free after boot >= {TARGET_HEAP_FREE_KB:g} KB",
          file=sys.stderr)
    return 0


def emulated_figures() -> tuple[list[str], str]:
    """The emulated S32's lines (J1's flash booted through tests/s32_bus.py), or none and why not."""
    sys.path[:0] = [str(ROOT / "tests")]
    import s32_bus

    why = s32_bus.missing()
    if why is not None:
        return [], why
    from bioscara.errors import BioscaraError
    from bioscara.joint import Joint
    from bioscara.link.v2 import V2Link

    with tempfile.TemporaryDirectory() as tmp:
        try:
            bus = s32_bus.EmulatedS32Bus(s32_bus.EmulatedS32Bus.flash_for("J1", pathlib.Path(tmp)))
        except s32_bus.EmulatorError as exc:
            return [], f"the emulated S32 did not boot: {str(exc).splitlines()[0][:160]}"
        try:
            return _measure(bus, Joint("J1", J1_ADDRESS, bus), V2Link), ""
        except (BioscaraError, s32_bus.EmulatorError) as exc:
            return [], f"the emulated S32 failed: {str(exc).splitlines()[0][:160]}"
        finally:
            bus.close()


def _measure(bus, joint, v2_link) -> list[str]:
    """Heap after boot (the firmware's log line), then instruction counts: estimates (one
    instruction a cycle; the emulator has no timing fidelity); last, those in words."""
    free = int(HEAP_LINE.search(bus.log).group(1))
    lines = [f"s32.heap_free_after_boot_kb {free / 1024:.1f}"]
    with bus.counting() as idle:
        bus.sleep(ESTIMATE_MS / 1000)
    lines.append(f"s32.main_loop_instructions_estimate {idle[0].per_iteration}")
    joint.init()
    with bus.counting() as legacy:
        joint.read_register("IDENTITY")  # 1 byte written, 10 read
    lines.append(f"s32.i2c_legacy_read_instructions_estimate {legacy[0].in_i2c}")
    joint.use_v2()
    assert isinstance(joint.link, v2_link)
    with bus.counting() as cycle:
        joint.cycle()  # a NONE frame of 7 bytes written, the state block's 8 read
    lines.append(f"s32.i2c_v2_cycle_instructions_estimate {cycle[0].in_i2c}")
    start_us = bus.now_us
    with bus.counting() as serving:
        for _ in range(V2_CYCLES):
            joint.cycle()
            bus.sleep(V2_PERIOD_S)
    v2_ms = (bus.now_us - start_us) / 1000
    lines.append(f"s32.main_loop_instructions_v2_estimate {serving[0].per_iteration}")
    joint.close()
    lines.append(
        f"estimates (no timing fidelity: one instruction taken as one cycle of 84 MHz): a main-loop iteration "
        f"{idle[0].per_iteration / 84:.0f} us of the 1000 us period with no host ({idle[0].iterations} in "
        f"{ESTIMATE_MS} ms), {serving[0].per_iteration / 84:.0f} us serving v2 to a host cycling every "
        f"{V2_PERIOD_S * 1000:g} ms ({serving[0].iterations} iterations in {v2_ms:.1f} ms: "
        f"{serving[0].iterations / v2_ms * 1000:.0f} Hz); the I2C1 interrupts run {legacy[0].in_i2c / 84:.0f} us "
        f"over a legacy IDENTITY read and {cycle[0].in_i2c / 84:.0f} us over a v2 cycle")
    return lines


if __name__ == "__main__":
    sys.exit(main(pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else "build/s32")))
