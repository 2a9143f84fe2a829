"""CircuitPython 10.2.1 on the emulated Pico as its users' tools see it: code.py from the CIRCUITPY
FAT image runs at boot, mpremote's raw REPL answers on the USB serial port, and the board's FAT
region of flash reads back as a FAT image. (A file CircuitPython's own code writes there did not
show up in the region even after os.sync(); nothing in the project needs it.)"""

from __future__ import annotations

from pathlib import Path

import serial

from chip import fsimage
from chip.board import EmulatedPico
from chip.testing import requires_circuitpython

pytestmark = requires_circuitpython


def test_code_py_from_a_fat_image_runs_at_boot_and_the_raw_repl_answers(tmp_path: Path) -> None:
    image = tmp_path / "circuitpy.img"
    # It keeps greeting: what a board prints before the host sets DTR is lost, as on USB.
    code = b"import time, greet\nwhile True:\n    print(greet.TEXT)\n    time.sleep(0.05)\n"
    image.write_bytes(fsimage.fat_image({"/code.py": code, "/lib/greet.py": b"TEXT = 'hello from CIRCUITPY'\n"}))
    with EmulatedPico(image, runtime="circuitpython") as pico:
        console = serial.Serial(pico.port(), timeout=60)
        try:
            assert console.read_until(b"hello from CIRCUITPY").endswith(b"hello from CIRCUITPY")
        finally:
            console.close()
        out = pico.exec("import sys\nprint(sys.implementation.name, sys.implementation.version[:3])")
        assert out.strip() == "circuitpython (10, 2, 1)"
        files = fsimage.read_fat_image(pico.fs_image())
    assert files["/code.py"] == code and files["/lib/greet.py"].startswith(b"TEXT")
