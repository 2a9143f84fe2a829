"""`bioscara panel --web` as a server: the secret token, and no panel left behind when it stops.
Real processes (the server, the panels it starts for each connection); waits are on conditions."""

from __future__ import annotations

import asyncio
import signal
import socket
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import aiohttp
import pytest

from tests.test_panel_web import eventually, free_port

TOKEN = "s3cret-for-the-test"


def children(pid: int) -> list[int]:
    found: list[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*/children"):
        try:
            found += [int(child) for child in task.read_text().split()]
        except OSError:
            pass
    return found


def alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False


@pytest.fixture
def server() -> Iterator[Callable[..., tuple[subprocess.Popen[str], int, str]]]:
    started: list[subprocess.Popen[str]] = []

    def start(*options: str) -> tuple[subprocess.Popen[str], int, str]:
        port = free_port()
        process = subprocess.Popen([sys.executable, "-m", "bioscara.cli", "panel", "--web", "--port", str(port),
                                    *options], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                   preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        started.append(process)
        assert process.stdout is not None
        first = process.stdout.readline()

        def listening() -> bool:
            with socket.socket() as s:
                return s.connect_ex(("127.0.0.1", port)) == 0
        assert eventually(listening, 30), first
        return process, port, first
    yield start
    for process in started:
        if process.poll() is None:
            process.kill()
        process.communicate()


async def connect(port: int, cookies: dict[str, str] | None = None, query: str = "") -> tuple[int, bytes]:
    """Open the panel's page and its websocket as the browser does; the HTTP status and the first bytes."""
    # unsafe=True: keep cookies from an IP address, as a browser does
    async with aiohttp.ClientSession(cookies=cookies, cookie_jar=aiohttp.CookieJar(unsafe=True)) as http:
        async with http.get(f"http://127.0.0.1:{port}/{query}") as page:
            if page.status != 200:
                return page.status, await page.read()
        try:
            async with http.ws_connect(f"ws://127.0.0.1:{port}/ws?width=100&height=30") as ws:
                message = await ws.receive(timeout=60)
                return 101, message.data if isinstance(message.data, bytes) else str(message.data).encode()
        except aiohttp.WSServerHandshakeError as exc:
            return exc.status, b""


def test_a_request_without_the_token_reaches_no_panel(server) -> None:  # type: ignore[no-untyped-def]
    process, port, first = server("--token", TOKEN)
    assert f"http://127.0.0.1:{port}/?token={TOKEN}" in first
    status, body = asyncio.run(connect(port))
    assert status == 403 and b"secret token" in body
    status, _ = asyncio.run(connect(port, cookies={"bioscara_panel_token": "wrong"}))
    assert status == 403
    assert children(process.pid) == [], "no panel was started for a request without the token"
    status, _ = asyncio.run(connect(port, query=f"?token={TOKEN}"))
    assert status == 101 and eventually(lambda: children(process.pid) != [], 30), "with it, a panel runs"


def test_served_beyond_this_machine_the_url_carries_a_random_token(server) -> None:  # type: ignore[no-untyped-def]
    _, port, first = server("--host", "0.0.0.0")
    assert f"http://0.0.0.0:{port}/?token=" in first and "(every network it is on)" in first
    token = first.split("token=")[1].split()[0]
    assert len(token) >= 24
    assert asyncio.run(connect(port))[0] == 403
    assert asyncio.run(connect(port, query=f"?token={token}"))[0] == 101


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_stopping_the_server_leaves_no_panel_behind(server, signum: int) -> None:  # type: ignore[no-untyped-def]
    process, port, _ = server()

    async def hold_a_session() -> list[int]:
        async with aiohttp.ClientSession() as http:
            async with http.ws_connect(f"ws://127.0.0.1:{port}/ws?width=100&height=30") as ws:
                await ws.receive(timeout=60)  # the panel runs and draws
                panels = children(process.pid)
                process.send_signal(signum)  # the browser tab is still open
                await asyncio.get_running_loop().run_in_executor(None, process.wait, 30)
                return panels
    panels = asyncio.run(hold_a_session())
    assert panels, "the session had started its panel"
    assert process.returncode is not None
    assert eventually(lambda: not any(alive(pid) for pid in panels), 10), "a panel outlived its server"
