"""Debug commands on the joint's USB serial console, without ever delaying the main loop.

`poll()` runs once per main-loop iteration: it takes at most one chunk of input that is already
waiting (the reader never blocks) and executes at most one command. The I/O is injected, so the
simulator serves the same console on a pseudo-terminal.

    status           flags, setpoints, position, velocity, configuration summary
    regs             the register reply caches, as bytes and decoded
    trace on|off     every stall-detection sample as one tab-separated line (TRACE_COLUMNS),
                     the columns the original firmware printed for its serial plotter
    log LEVEL        ERROR, WARN, INFO or DEBUG
    help

The commands live in debug_commands.py, imported by the first complete line: until someone types,
the board keeps only the line reader (a few KB of heap more for the control loop).
"""

from ..micro import const

_CHUNK = const(16)
_LINE = const(64)


class UsbStdio:
    """The board's USB serial (stdin/stdout) without ever waiting: `read(buf)` takes only bytes
    already there, `write(line)` (a str or its bytes: MicroPython's stdout takes both) drops the
    line (counted in `dropped`) when USB cannot take it now, e.g. a host that keeps the port open
    without reading (stdout would block up to 500 ms)."""

    def __init__(self):
        import select
        import sys

        self._in_poll = select.poll()
        self._in_poll.register(sys.stdin, select.POLLIN)
        self._out_poll = select.poll()
        self._out_poll.register(sys.stdout, select.POLLOUT)
        self._stdin = sys.stdin.buffer
        self._stdout = sys.stdout
        self._one = bytearray(1)
        self.dropped = 0
        _ready(self._in_poll)  # ipoll allocates the tuple it reuses on its first call
        _ready(self._out_poll)

    def read(self, buf):
        n = 0
        while n < len(buf) and _ready(self._in_poll):
            if not self._stdin.readinto(self._one):
                break  # end of input: readable, but nothing to read
            buf[n] = self._one[0]
            n += 1
        return n

    def write(self, line):
        if _ready(self._out_poll):
            self._stdout.write(line)
            self._stdout.write("\n")
        else:
            self.dropped += 1


def _ready(poller):
    for _ in poller.ipoll(0):  # ipoll reuses one result tuple: poll() would build a list each call
        return True
    return False


class DebugConsole:
    """`read(buf)` returns how many bytes it put in buf (0 when none wait); `write(line)` prints a
    line: a str, or (the trace) a bytes-like view of a buffer that is reused after the call."""

    def __init__(self, core, read, write):
        self.core = core
        self._read = read
        self._write = write
        self._chunk = bytearray(_CHUNK)
        self._pos = 0
        self._end = 0
        self._line = bytearray(_LINE)
        self._len = 0
        self._overflow = False
        self._commands = None  # debug_commands.Commands, from the first complete line on

    def poll(self):
        """Take waiting input; run a command if a line is complete. Bounded work, never waits."""
        if self._pos == self._end:
            self._pos = 0
            self._end = self._read(self._chunk) or 0
        chunk = self._chunk
        while self._pos < self._end:
            byte = chunk[self._pos]
            self._pos += 1
            if byte == 10 or byte == 13:
                if self._len or self._overflow:
                    self._finish_line()
                    return  # one command per main-loop iteration
            elif self._len < _LINE:
                self._line[self._len] = byte
                self._len += 1
            else:
                self._overflow = True

    def _finish_line(self):
        if self._overflow:
            self._write("error: line longer than %d characters ignored" % _LINE)
        else:
            try:
                words = bytes(self._line[:self._len]).decode().split()
            except UnicodeError:  # MicroPython has no errors="replace"
                words = None
                self._write("error: not a text command")
            if words:
                self.execute(words[0].lower(), words[1:])
        self._len = 0
        self._overflow = False

    def execute(self, name, args):
        if self._commands is None:
            from .debug_commands import Commands
            self._commands = Commands(self.core, self._write)
        self._commands.execute(name, args)
