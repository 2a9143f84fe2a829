"""What the running joint keeps of the spec (regtable.py) and what the board forgets after boot."""

import sys

from joint import app, startup
from joint.spec import protocol as P, protocol_v2 as V
from joint.spec.regtable import NOT_A_COMMAND, RegisterTable
from joint.console.debug import DebugConsole
from test_app import Machine, _boot

ON_BOARD_PORT = sys.implementation.name == "micropython"


def test_the_register_table_says_what_the_spec_says():
    table = RegisterTable()
    for addr in range(256):
        reg = P.BY_ADDR[addr]
        assert table.name(addr) == (reg.name if reg else "0x%02x" % addr)
        if addr < len(table.blocking):
            assert table.blocking[addr] == (1 if reg and reg.blocking else 0)
            assert table.reply_size[addr] == (reg.rsize if reg and reg.readable else 0)
        else:
            assert reg is None
        size = table.command_size(addr)
        assert (size != NOT_A_COMMAND) == V.is_command(reg), addr
        if size != NOT_A_COMMAND:
            assert size == reg.wsize
        if reg is not None and reg.readable:
            payload = bytes(range(1, 1 + reg.rsize))
            assert table.decode(addr, payload) == reg.decode(payload)
    for flags in range(256):
        assert table.describe_flags(flags) == P.describe_flags(flags)


def test_the_board_forgets_the_boot_only_modules_and_runs_without_them():
    machine = Machine()
    core, cfg, log, lines = _boot('{"joint": "J2", "address": 18, "stall": {"gain": -1}}', machine)
    switch = app.join_bus(machine, core, cfg, log)
    out = []
    console = DebugConsole(core, lambda buf: 0, out.append)
    console.execute("status", [])
    console.execute("regs", [])
    core.on_frame(bytearray((0x40,)), 1)  # an unknown register: the main loop logs why
    for _ in range(5):
        core.service()
        switch.service()
        console.poll()
    assert any("rejected a frame for register 0x40: reason %d" % P.REJECT_UNKNOWN_REGISTER in line
               for line in lines), lines
    assert any(line.startswith("0x0f PING") for line in out), out
    prefix = app.__name__[:-len("app")]
    kept = [name for name in startup.BOOT_ONLY if prefix + name in sys.modules]
    # The host (CPython) keeps the spec: its package uses it. The board's port forgets it.
    if ON_BOARD_PORT:
        assert kept == [], kept
    else:
        assert "config.schema" in kept and "spec.protocol" in kept, kept


def test_an_idle_console_keeps_only_its_line_reader_and_the_first_line_loads_the_commands():
    machine = Machine()
    core, cfg, log, lines = _boot('{"joint": "J2", "address": 18}', machine)
    keys = bytearray(b"help\n")
    out = []

    def read(buf):
        n = len(keys) if typing[0] else 0
        buf[:n] = keys[:n]
        typing[0] = False
        return n

    typing = [False]
    console = DebugConsole(core, read, out.append)
    for _ in range(5):
        console.poll()
    assert console._commands is None and out == []
    typing[0] = True
    console.poll()
    assert console._commands is not None and out[0].startswith("status"), out
