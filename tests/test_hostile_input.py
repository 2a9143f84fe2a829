"""Bad input of every kind gets one clear line and a usage/config exit status, never a traceback:
scripts, configuration files and arguments with non-UTF-8 bytes, deep nesting, huge values."""

from __future__ import annotations

import io
import os
import subprocess
import sys
from pathlib import Path

import pytest

from bioscara import cli

NOT_UTF8 = b"read j1 PING\n\xff\xfe\x80 configure\n"


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def bad_configs(tmp_path: Path) -> dict[str, bytes]:
    shipped = (Path(cli.__file__).parent / "data" / "default.toml").read_bytes()
    return {
        "not-utf8.toml": shipped.replace(b'url = "sim:"', b'url = "sim:\xff"'),
        "deep.toml": b"x = " + b"[" * 5000 + b"]" * 5000 + b"\n",
        "deep-tables.toml": b"x = " + b"{a = " * 3000 + b"1" + b"}" * 3000 + b"\n",
        "huge-int.toml": shipped.replace(b"reduction = 35.0", b"reduction = 1" + b"0" * 400),
        "huge-float.toml": shipped.replace(b"max_velocity = 1.0 ", b"max_velocity = 1e999"),
        "nan.toml": shipped.replace(b"max_velocity = 1.0 ", b"max_velocity = nan"),
        "huge-address.toml": shipped.replace(b"address = 0x11", b"address = 0x" + b"f" * 300),
        "long-key.toml": shipped + b"[" + b"k" * 100_000 + b"]\n",
        "binary.toml": bytes(range(256)) * 16,
        "empty.toml": b"",
    }


def test_bad_configuration_files(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for name, data in bad_configs(tmp_path).items():
        path = tmp_path / name
        path.write_bytes(data)
        code, out, err = run(capsys, "scan", "--config", str(path))
        assert code == 2, (name, err)
        assert err.startswith("error: ") and str(path) in err and "Traceback" not in out + err, (name, err)
        assert all(len(line) < 400 for line in err.splitlines()), (name, "a line the terminal can show")


def test_bad_shell_scripts(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                           monkeypatch: pytest.MonkeyPatch) -> None:
    script = tmp_path / "script.txt"
    script.write_bytes(NOT_UTF8)
    code, out, err = run(capsys, "shell", "--script", str(script))
    assert code == 1 and f"{script}:2: error: not UTF-8 text" in err and "Traceback" not in err
    assert "> read j1 PING" in out, "the lines before it ran"
    deep = tmp_path / "deep.txt"
    deep.write_text(f"run {deep}\n")  # a script that runs itself
    code, _, err = run(capsys, "shell", "--script", str(deep))
    assert code == 1 and "already running" in err
    (tmp_path / "runner.txt").write_text(f"run {script}\nrun {tmp_path}\n")
    code, _, err = run(capsys, "shell", "--keep-going", "--script", str(tmp_path / "runner.txt"))
    assert code == 1 and "not UTF-8 text" in err and "is a directory" in err.lower()
    for missing in (tmp_path / "nope.txt", tmp_path):
        code, _, err = run(capsys, "shell", "--script", str(missing))
        assert code == 2 and err.startswith("error: cannot read") and str(missing) in err
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(NOT_UTF8), encoding="utf-8"))
    code, out, err = run(capsys, "shell")
    assert code == 1 and "<stdin>:2: error: not UTF-8 text" in err
    long_line = "read j1 " + "x" * 1_000_000
    monkeypatch.setattr(sys, "stdin", io.StringIO(long_line + "\nset j1 position 1e999\nset j1 position nan\n"))
    code, out, err = run(capsys, "shell", "--keep-going")
    assert code == 1 and err.count("error:") == 3 and "Traceback" not in err


@pytest.mark.parametrize("argv", [
    ("info", "j\udcff"),
    ("move", "j1", "1e999"),
    ("move", "j1", "nan"),
    ("move", "j1", "1" + "0" * 5000),
    ("move", "j\udcff", "1"),
    ("home", "j1", "--timeout", "-5"),
    ("home", "j1", "--timeout", "nan"),
    ("home", "j1", "--rate", "1e999"),
    ("monitor", "--samples", "0"),
    ("monitor", "--samples", "9" * 5000),
    ("monitor", "--duration", "-1"),
    ("monitor", "--record", "/nonexistent/dir/run.csv", "--samples", "1"),
    ("scan", "--config", "/nonexistent/\udcff.toml"),
    ("scan", "--bus", "serial:/dev/\udcffnope"),
    ("scan", "--bus", "smbus:\udcff"),
    ("scan", "--bus", "serial:/dev/null?timeout=1e999"),
    ("scan", "--bus", "serial:/dev/null?timeout=nan"),
    ("scan", "--bus", "serial:/dev/null?baud=" + "9" * 5000),
    ("plot", "/nonexistent/\udcff.csv"),
    ("console", "/dev/\udcffnope", "-c", "status"),
    ("flash", "/dev/\udcffnope", "--joint", "j1", "--dry-run"),
    ("shell", "--script", "/nonexistent/\udcff"),
    ("shell", "--rate", "nan"),
    ("sim", "bogus"),
])
def test_bad_arguments(argv: tuple[str, ...], capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, *argv)
    assert code in (1, 2) and "Traceback" not in out + err, err
    assert err.strip() and len(err.strip().splitlines()) <= 2, err


def test_the_installed_command_never_shows_a_traceback_for_undecodable_arguments(tmp_path: Path) -> None:
    env = dict(os.environ, LC_ALL="C.UTF-8")
    result = subprocess.run([sys.executable, "-m", "bioscara.cli", "info", os.fsdecode(b"j\xff")],
                            capture_output=True, env=env, timeout=60)
    assert result.returncode == 2 and b"Traceback" not in result.stderr and b"no joint" in result.stderr
