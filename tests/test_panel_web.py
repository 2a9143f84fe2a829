"""`bioscara panel --web` in a real headless browser (Debian's chromium, driven by Playwright):
the page renders the panel and a mouse click on a button reaches the app."""

from __future__ import annotations

import io
import os
import shutil
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

CHROMIUM = shutil.which("chromium")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed "
                                "(`make test` installs it with apt-get where it may)")
BROWSER_FLAGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-sync",
                 "--disable-background-networking", "--disable-component-update"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def eventually(check: Callable[[], bool], seconds: float) -> bool:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if check():
            return True
        time.sleep(0.25)
    return check()


def configure_buttons(png: bytes) -> list[tuple[int, int]]:
    """Pixels inside a Configure button: Textual's warning orange, filled (the frames' orange lines
    are a pixel or two thick, a button is a block)."""
    from PIL import Image

    image = Image.open(io.BytesIO(png)).convert("RGB")
    width, height = image.size
    pixels = image.load()

    def orange(x: int, y: int) -> bool:
        r, g, b = pixels[x, y]
        return r > 230 and 130 < g < 190 and b < 90
    return [(x, y) for y in range(0, height - 6, 2) for x in range(0, width - 6, 2)
            if orange(x, y) and orange(x + 6, y) and orange(x, y + 6)]


def test_the_web_panel_renders_and_a_click_configures_the_arm(tmp_path: Path) -> None:
    from playwright.sync_api import sync_playwright

    port = free_port()
    env = dict(os.environ, XDG_STATE_HOME=str(tmp_path))
    server = subprocess.Popen([sys.executable, "-m", "bioscara.cli", "panel", "--web", "--port", str(port)],
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    try:
        assert server.stdout is not None
        first = server.stdout.readline()
        assert f"serving on http://127.0.0.1:{port} (this machine only)" in first

        def listening() -> bool:
            with socket.socket() as s:
                return s.connect_ex(("127.0.0.1", port)) == 0
        assert eventually(listening, 30)
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=CHROMIUM, args=BROWSER_FLAGS)
            try:
                page = browser.new_page(viewport={"width": 1600, "height": 1000})
                page.goto(f"http://127.0.0.1:{port}")
                orange: list[tuple[int, int]] = []

                def two_configure_buttons() -> bool:  # the arm's and the gripper's, one above the other
                    orange[:] = configure_buttons(page.screenshot())
                    return bool(orange) and max(y for _, y in orange) - min(y for _, y in orange) > 40
                assert eventually(two_configure_buttons, 60), "the panel never rendered in the browser"
                top = min(y for _, y in orange)
                arm_button = [(x, y) for x, y in orange if y < top + 30]
                x = sum(x for x, _ in arm_button) / len(arm_button)
                y = sum(y for _, y in arm_button) / len(arm_button)
                page.mouse.click(x, y)

                def arm_configured() -> bool:  # its button turned to Activate: only the gripper's is orange
                    remaining = configure_buttons(page.screenshot())
                    return bool(remaining) and min(y for _, y in remaining) > top + 30
                assert eventually(arm_configured, 30), "the click did not reach the panel"
            finally:
                browser.close()
    finally:
        server.terminate()
        try:
            server.wait(10)
        except subprocess.TimeoutExpired:
            server.kill()
