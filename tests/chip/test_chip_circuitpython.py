"""CircuitPython 10.2.1 on the emulated Pico as its users' tools see it: code.py from the CIRCUITPY
FAT image runs at boot, the REPL and mpremote's raw REPL answer on the USB serial port, and what
CircuitPython writes to CIRCUITPY lands in that region of flash."""

from __future__ import annotations

from pathlib import Path

import serial

from chip import fsimage
from chip.board import EmulatedPico
from chip.testing import requires_circuitpython

pytestmark = requires_circuitpython


def test_code_py_from_a_fat_image_runs_at_boot_and_the_raw_repl_answers(tmp_path: Path) -> None:
    image = tmp_path / "circuitpy.img"
    # It keeps greeting: what a board prints before the host sets DTR is lost, as on USB. boot.py
    # gives CircuitPython's own code the drive (the USB host then only reads it).
    code = b"import time, greet\nwhile True:\n    print(greet.TEXT)\n    time.sleep(0.05)\n"
    boot = b"import storage\nstorage.remount('/', readonly=False)\n"
    image.write_bytes(fsimage.fat_image({"/code.py": code, "/lib/greet.py": b"TEXT = 'hello from CIRCUITPY'\n",
                                         "/boot.py": boot}))
    with EmulatedPico(image, runtime="circuitpython") as pico:
        console = serial.Serial(pico.port(), timeout=60)
        try:
            assert console.read_until(b"hello from CIRCUITPY").endswith(b"hello from CIRCUITPY")
        finally:
            console.close()
        out = pico.exec("import os, sys\nwith open('/note.txt', 'w') as f: f.write('on flash')\nos.sync()\n"
                        "print(sys.implementation.name, sys.implementation.version[:3])")
        assert out.strip() == "circuitpython (10, 2, 1)"
        files = fsimage.read_fat_image(pico.fs_image())
    assert files["/note.txt"] == b"on flash"
    assert files["/code.py"] == code
