"""What the running joint keeps of the register spec (protocol.py): names, flag effects that the
main loop reads, mailbox payload sizes, reply formats and the names its log lines and console
print. Reject reasons and homing outcomes it logs by number (their texts took about 1.5 KB of the
board's heap); the host's console (serial_console.in_words) says them in words.

protocol.py's Register and Field objects are the spec for the host and for the joint's boot; on
the board they and their code take about 16 KB of heap. A `RegisterTable` copies the few facts
the joint needs after boot out of the spec once, so that the board forgets protocol.py after boot
(startup.drop_boot_only). Nothing here may hold a protocol.py object, or the spec would stay.
"""

import struct
from ..micro import const

NOT_A_COMMAND = const(0xFF)  # command_size(): the register may not travel in the v2 mailbox


class RegisterTable:
    """The spec's facts by register address, built once at boot."""

    def __init__(self):
        from . import protocol as P  # the spec, at boot only: not kept (see the module doc)
        from .protocol_v2 import is_command

        space = 1 + max(reg.addr for reg in P.REGISTERS)  # addresses the spec uses
        names = [None] * space
        self.blocking = bytearray(space)  # by address below `space` (commands the IRQ accepted)
        self.reply_size = bytearray(space)  # payload bytes of a read; 0: not readable
        self._command_sizes = bytearray(NOT_A_COMMAND for _ in range(space))
        self._formats = {}  # struct format of each readable register's reply payload
        for reg in P.REGISTERS:
            addr = reg.addr
            names[addr] = reg.name
            self.blocking[addr] = reg.blocking
            if reg.readable:
                self.reply_size[addr] = reg.rsize
                self._formats[addr] = reg.rfmt
            if is_command(reg):
                self._command_sizes[addr] = reg.wsize
        self._names = tuple(names)
        self._flags = P.FLAG_NAMES

    def command_size(self, cmd):
        """Payload bytes of register `cmd` (any byte) in a v2 mailbox; NOT_A_COMMAND if it may not
        travel there. Allocation-free."""
        sizes = self._command_sizes
        return sizes[cmd] if cmd < len(sizes) else NOT_A_COMMAND

    def name(self, addr):
        """The register's name; its address in hex if the spec has none."""
        if 0 <= addr < len(self._names) and self._names[addr] is not None:
            return self._names[addr]
        return "0x%02x" % addr

    def decode(self, addr, payload):
        """Values of a readable register's reply payload (as Register.decode)."""
        return struct.unpack(self._formats[addr], payload)

    def describe_flags(self, flags):
        """The flags byte by name, as protocol.describe_flags."""
        names = [name for bit, name in self._flags if flags & bit]
        return "|".join(names) if names else "-"
