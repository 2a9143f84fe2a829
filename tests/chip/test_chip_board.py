"""The emulated Pico as a user's tools see it: a MicroPython REPL on a serial port, a littlefs in flash."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import serial

from bioscara.mpboard import MpremoteBoard
from chip import fsimage
from chip.board import BoardSpec, EmulatedPico
from chip.testing import requires_chip

pytestmark = requires_chip


def test_mpremote_runs_code_on_the_board_through_its_pty() -> None:
    with EmulatedPico() as pico:
        mpremote = [sys.executable, "-m", "mpremote", "connect", pico.port()]
        result = subprocess.run([*mpremote, "exec", "print(6 * 7)"], capture_output=True, text=True, timeout=60)
        assert result.returncode == 0, result.stderr
        assert result.stdout.strip() == "42"
        # The pty outlives a client: a second connection works as the first did.
        again = subprocess.run([*mpremote, "exec", "print('again')"], capture_output=True, text=True, timeout=60)
        assert again.stdout.strip() == "again"
        assert pico.seconds() > 0


def test_the_probe_of_the_board_is_what_the_prebuilt_image_is_built_for() -> None:
    with EmulatedPico() as pico:
        board = MpremoteBoard(pico.port())
        try:
            assert board.info() == fsimage.STOCK_PICO
        finally:
            board.close()


def test_micropython_formats_blank_flash_and_its_files_land_in_flash() -> None:
    # Blank flash: MicroPython's _boot.py formats littlefs at 0xA0000, which needs the emulated
    # flash chip to erase and program; littlefs-python then reads what MicroPython wrote.
    with EmulatedPico() as pico:
        out = pico.exec("import os\nwith open('/note.txt', 'w') as f: f.write('on flash')\n"
                        "print(os.statvfs('/')[:3])")
        assert out.strip() == "(4096, 4096, 352)"
        image = pico.fs_image()
    assert fsimage.read_image(image)["/note.txt"] == b"on flash"


def test_a_prebuilt_image_boots_its_main_py(tmp_path: Path) -> None:
    image = tmp_path / "fs.img"
    # It keeps greeting: what a board prints before the host opens the port is lost, as on USB.
    greet = b"import time\nwhile True:\n    print('hello from flash')\n    time.sleep_ms(50)\n"
    image.write_bytes(fsimage.littlefs_image({"/main.py": b"import lib.greet\n", "/lib/greet.py": greet}))
    with EmulatedPico(image) as pico:
        console = serial.Serial(pico.port(), timeout=30)
        try:
            assert console.read_until(b"hello from flash").endswith(b"hello from flash")
        finally:
            console.close()


def test_a_paused_board_steps_exactly_the_emulated_time_asked_and_shuts_down_cleanly() -> None:
    with EmulatedPico(paused=True) as pico:
        assert pico.seconds() == 0
        assert pico.run_for(0.05) == 0.05
        assert pico.run_for(0.05) == 0.1
        assert pico.seconds() == 0.1
        port, process = pico.port(), pico.process
    assert process is not None and process.returncode == 0
    assert not os.path.exists(port)


def test_two_boards_in_one_process_each_have_their_own_pty(tmp_path: Path) -> None:
    image = tmp_path / "fs.img"
    image.write_bytes(fsimage.littlefs_image({"/name.txt": b"second"}))
    with EmulatedPico(boards=[BoardSpec("first"), BoardSpec("second", fs_image=image)]) as pico:
        assert pico.port("first") != pico.port("second")
        read = "import os\nprint(open('name.txt').read() if 'name.txt' in os.listdir() else 'blank')"
        assert pico.exec(read, "first").strip() == "blank"
        assert pico.exec(read, "second").strip() == "second"
        boards = pico.request("time")["boards"]
        assert abs(boards["first"]["nanos"] - boards["second"]["nanos"]) <= pico.quantum_ns


PLUGIN = """
export function attach(world, boards, options) {
  const board = boards.get('pico');
  const seen = { fired: null };
  board.afterCycles(options.cycles, (b) => { seen.fired = b.cycles; });
  return { name: 'probe', control(command, msg) { return { command, echo: msg.x, fired: seen.fired }; } };
}
"""


def test_a_plugin_schedules_on_the_cpu_clock_and_answers_on_the_control_channel(tmp_path: Path) -> None:
    plugin = tmp_path / "probe.mjs"
    plugin.write_text(PLUGIN)
    with EmulatedPico(paused=True, plugins=[{"module": str(plugin), "options": {"cycles": 125_000}}]) as pico:
        assert pico.request("probe.look", x=5)["fired"] is None
        pico.run_for(0.002)
        reply = pico.request("probe.look", x=5)
        assert (reply["command"], reply["echo"], reply["fired"]) == ("look", 5, 125_000)
