"""`bioscara flash --runtime circuitpython`: the CIRCUITPY image, the copy onto a drive (a
directory, as a user's computer mounts it), verification by hash, refusals; `bioscara ports`
telling a CircuitPython board from a MicroPython one by its USB identity. The image boots on the
emulated Pico in tests/chip/test_chip_circuitpython_joint.py."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bioscara import circuitpy, cli
from bioscara import firmware_flash as flash
from bioscara.commands.ports import runtime_of
from bioscara.mpboard import FlashError

BOOT_OUT = "Adafruit CircuitPython 10.2.1 on 2026-12-02; Raspberry Pi Pico with rp2040\n"


@pytest.fixture
def drive(tmp_path: Path) -> Path:
    """An empty CIRCUITPY as CircuitPython leaves it after its first boot."""
    root = tmp_path / "CIRCUITPY"
    root.mkdir()
    (root / "boot_out.txt").write_text(BOOT_OUT)
    (root / "settings.toml").write_text("# the user's\n")
    return root


def run_cli(*args: str) -> tuple[int, dict]:
    import contextlib
    import io

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = cli.main(["--json", *args])
    return code, json.loads(out.getvalue()) if out.getvalue().strip() else {}


def test_the_image_is_the_firmware_for_bytecode() -> None:
    image = circuitpy.build_image("J1")
    sources = flash.firmware_sources(circuitpy.MANIFEST)
    assert image.files["/code.py"].endswith(b"from joint.cpy import app\n\napp.run()\n")
    assert json.loads(image.files["/joint_config.json"])["joint"] == "J1"
    assert {p for p in image.files if p.startswith("/lib/")} == {f"/lib/{n[:-3]}.mpy" for n in sources}
    assert all(data.startswith(b"C\x06") for p, data in image.files.items() if p.endswith(".mpy"))
    stepgen = sources["joint/pico/stepgen.py"]
    changed = circuitpy.circuitpython_source(stepgen)
    assert stepgen.count(b"@micropython.viper") == 2 and b"\n@micropython" not in changed
    assert changed.count(b"\n") == stepgen.count(b"\n")  # tracebacks keep their line numbers
    assert changed.count(b"# @micropython.viper (bytecode on CircuitPython)") == 2
    assert "cpy/app.py" not in " ".join(flash.firmware_sources()), "MicroPython boards do not get it"
    assert "joint/links/cp_target.py" in sources and "joint/sim/joint.py" not in sources


def test_no_deployed_kernel_builds_the_long_int_sign_masks() -> None:
    """m = 2**31 and k = 2**32 - 1 are long ints on CircuitPython: three allocations a use."""
    for name, source in flash.firmware_sources(circuitpy.MANIFEST).items():
        changed = circuitpy.circuitpython_source(source)
        assert b"m <<= 31" not in changed and b"] + m) & k) - m" not in changed, name
        assert changed.count(b"\n") == source.count(b"\n"), name


def _bytecode_module(name: str):
    """Firmware module `name` ("joint.motion.tickramp") as the CircuitPython image runs it, under
    CPython: its source through circuitpython_source, executed as a module of the same package."""
    import importlib.util
    import types

    original = importlib.import_module(name)
    spec = importlib.util.find_spec(name)
    module = types.ModuleType(name + "_bytecode")
    module.__package__ = original.__package__
    module.__file__ = spec.origin
    code = circuitpy.circuitpython_source(Path(spec.origin).read_bytes())
    exec(compile(code, spec.origin, "exec"), module.__dict__)  # noqa: S102 -- the firmware's own source
    return original, module


def _words(rng, n: int, span: int = 1 << 24) -> list[int]:
    return [rng.randrange(-span, span) for _ in range(n)]


def test_the_kernels_without_sign_extension_compute_what_the_firmware_does() -> None:
    """Ramp, velocity estimator, closed-loop resync and step bookkeeping on random int32 states:
    the deployed bytecode and the firmware's source leave the same words and return the same."""
    import random
    from array import array

    from pico_fakes import FakeSM

    rng = random.Random(22)
    ramp, ramp_cp = _bytecode_module("joint.motion.tickramp")
    velocity, velocity_cp = _bytecode_module("joint.motion.velocity")
    motor, motor_cp = _bytecode_module("joint.pico.motor")
    steps, steps_cp = _bytecode_module("joint.pico.stepgen")
    for _ in range(400):
        state = _words(rng, 8)
        state[3] = rng.randrange(4)  # the mode
        state[5:8] = [rng.randrange(1 << 22) for _ in range(3)]  # vmax, amax, dmax >= 0
        ticks = rng.randrange(1, 5)
        a, b = array("i", state), array("i", state)
        ramp.run_ramp(a, ticks)
        ramp_cp.run_ramp(b, ticks)
        assert a == b, state
        state = [1000, 8, 500] + _words(rng, 4, 1 << 20) + [1 << 21]
        count = rng.randrange(-1 << 20, 1 << 20)
        a, b = array("i", state), array("i", state)
        assert velocity.update_velocity(a, count) == velocity_cp.update_velocity(b, count) and a == b
        encoder, driver, ramp_words = _words(rng, 8, 1 << 20), _words(rng, 4), _words(rng, 8)
        threshold = rng.randrange(1, 200)
        words = [array("i", w) for w in (encoder, driver, ramp_words)]
        words_cp = [array("i", w) for w in (encoder, driver, ramp_words)]
        assert motor._resync(*words, threshold) == motor_cp._resync(*words_cp, threshold) and words == words_cp
        state = _words(rng, 4) + [rng.choice((1, 16, 256)), 25, 1200, 0]
        state[2] = rng.randrange(5)  # bursts in flight
        target, window = rng.randrange(-1 << 24, 1 << 24), rng.randrange(100, 5000)
        a, b = array("i", state), array("i", state)
        sm, sm_cp = FakeSM(), FakeSM()
        assert steps.issue_steps(a, sm, 0, target, window) == steps_cp.issue_steps(b, sm_cp, 0, target, window)
        assert a == b and sm.tx == sm_cp.tx
        assert sm.finish() == sm_cp.finish()
        steps.poll_steps(a, sm, 0)
        steps_cp.poll_steps(b, sm_cp, 0)
        assert a == b


def test_flash_copies_verifies_and_a_second_run_changes_nothing(drive: Path) -> None:
    code, report = run_cli("flash", "--runtime", "circuitpython", "--drive", str(drive), "--joint", "j1")
    assert code == 0 and report["verified"] and report["board"] == BOOT_OUT.strip()
    image = circuitpy.build_image("J1")
    for path, data in image.files.items():
        assert (drive / path.lstrip("/")).read_bytes() == data
    assert (drive / "settings.toml").read_text() == "# the user's\n", "nothing else is touched"
    assert not list(drive.rglob("*.part"))
    code, again = run_cli("flash", "--runtime", "circuitpython", "--drive", str(drive), "--joint", "j1")
    assert code == 0 and again["write_bytes"] == 0 and not again["added"] and not again["updated"]


def test_a_stale_file_goes_and_a_changed_one_is_rewritten(drive: Path) -> None:
    circuitpy.apply(circuitpy.plan(drive, "J1"))
    (drive / "lib/joint/old.mpy").write_bytes(b"C\x06gone")
    (drive / "lib/joint/app.mpy").write_bytes(b"damaged")
    plan = circuitpy.plan(drive, "J2")
    assert plan.stale == ("/lib/joint/old.mpy",)
    assert set(plan.updated) == {"/lib/joint/app.mpy", "/joint_config.json"}
    circuitpy.apply(plan)
    assert not (drive / "lib/joint/old.mpy").exists()
    assert json.loads((drive / "joint_config.json").read_bytes())["joint"] == "J2"


def test_verification_names_a_file_that_did_not_land(drive: Path) -> None:
    plan = circuitpy.plan(drive, "J1")
    circuitpy.apply(plan)
    (drive / "lib/joint/core/irq.mpy").write_bytes(b"C\x06short")
    with pytest.raises(FlashError, match=r"/lib/joint/core/irq.mpy on .* has SHA-256"):
        circuitpy.verify(plan)


def test_a_directory_that_is_no_circuitpy_drive_is_refused_untouched(tmp_path: Path) -> None:
    code, _ = run_cli("flash", "--runtime", "circuitpython", "--drive", str(tmp_path), "--joint", "j1")
    assert code != 0 and list(tmp_path.iterdir()) == []
    with pytest.raises(FlashError, match="no such directory"):
        circuitpy.plan(tmp_path / "absent", "J1")


@pytest.mark.parametrize("args, message", [
    (["--drive", "X", "--joint", "j1"], "add --runtime circuitpython"),
    (["--runtime", "circuitpython", "--joint", "j1"], "give --drive"),
    (["--runtime", "circuitpython", "/dev/ttyACM0", "--drive", "X", "--joint", "j1"], "PORT is for MicroPython"),
])
def test_mixed_up_options_get_a_clear_error(args: list[str], message: str, capsys: pytest.CaptureFixture) -> None:
    assert cli.main(["flash", *args]) != 0
    assert message in capsys.readouterr().err


@pytest.mark.parametrize("identity, runtime", [
    ((0x239A, 0x80F4, "Pico", "CircuitPython CDC control"), "circuitpython"),  # CircuitPython on a Pico
    ((0x239A, 0x8120, "Feather RP2040", None), "circuitpython"),
    ((0x2E8A, 0x0005, "Board in FS mode", "Board CDC"), "micropython"),  # MicroPython on a Pico
    ((0xF055, 0x9800, None, None), "micropython"),
    ((0x0403, 0x6001, "FT232R USB UART", None), None),
])
def test_ports_tells_the_runtime_from_the_usb_identity(identity: tuple, runtime: str | None) -> None:
    assert runtime_of(*identity) == runtime


def test_circuitpython_store_q_packs_the_bytes_the_firmware_packs() -> None:
    """cpy/fixed.store_q (byte by byte, small ints only) writes exactly the float32 that
    motion.fixed.store_q and struct.pack write, across every exponent and the rounding edges."""
    import random
    import struct

    from bioscara.firmware.cpy.fixed import store_q as cp_store_q
    from bioscara.firmware.motion.fixed import LIMIT, store_q

    rng = random.Random(22)
    values = [0, 1, -1, LIMIT, -LIMIT, 0xFFFFFF, 0x1000000, 0x1000001, 0x1FFFFFF, 0x2000003, 0x3FFFFFE]
    values += [rng.randrange(-LIMIT, LIMIT + 1) >> rng.randrange(31) for _ in range(3000)]
    for n in values:
        for q in (0, 12, 16, 30):
            mine, theirs = bytearray(4), bytearray(4)
            cp_store_q(mine, n, q)
            store_q(theirs, n, q)
            assert mine == theirs == struct.pack("<f", n / 2**q), (n, q)
