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
"""

from . import log as L
from .fixed import ANGLE_Q, RPM_Q

try:
    from micropython import const
except ImportError:
    def const(value):
        return value

TRACE_COLUMNS = ("raw", "despiked", "filtered", "speed", "set_speed", "threshold", "stall")
TRACE_UNITS = ("usteps", "usteps", "usteps", "rad/s", "rad/s", "usteps", "")
HELP = (
    "status        flags, setpoints, position, velocity, configuration",
    "regs          register reply caches",
    "trace on|off  stall-detection samples: " + " ".join(TRACE_COLUMNS),
    "log LEVEL     ERROR, WARN, INFO or DEBUG",
)
_CHUNK = const(16)
_LINE = const(64)
_ANGLE = 1 << ANGLE_Q
_RPM = 1 << RPM_Q


class UsbStdio:
    """The board's USB serial (stdin/stdout) without ever waiting: `read(buf)` takes only bytes
    already there, `write(line)` drops the line (counted in `dropped`) when USB cannot take it now,
    e.g. a host that keeps the port open without reading (stdout would block up to 500 ms)."""

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
    """`read(buf)` returns how many bytes it put in buf (0 when none wait); `write(text)` prints a line."""

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
        self._commands = {"status": self._status, "regs": self._regs, "trace": self._trace_cmd,
                          "log": self._log, "help": self._help}

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
        command = self._commands.get(name)
        if command is None:
            self._write("error: unknown command %r; type help" % name)
        else:
            command(args)

    # ---- commands ----

    def _help(self, args):
        for line in HELP:
            self._write(line)

    def _status(self, args):
        core = self.core
        cfg = core.cfg
        write = self._write
        write("%s at 0x%02x  flags %s  task %s  ready %s  disabled %s" % (
            cfg.joint, cfg.address or 0, core.registers.describe_flags(core.flags), core.task_name or "-",
            _yes(core.ready), _yes(core.disabled)))
        write("setpoints  position %.3f deg  velocity %.3f rpm  positioning %s" % (
            core.q_set / _ANGLE, core.qd_set / _RPM, _yes(core.positioning)))
        hal = core.hal
        if hal is None:
            write("motor  unavailable")
        else:
            try:
                write("motor  position %.3f deg  velocity %.3f rpm  pid error %d usteps" % (
                    hal.angle_moved() / _ANGLE, hal.encoder_rpm() / _RPM, hal.pid_error()))
            except Exception as exc:  # a failed driver must not take the console down
                write("motor  error %r" % (exc,))
        write("currents  drive %d %%  hold %d %%  closed loop %s  stallguard %s (sensitivity %d)" % (
            core.drive_current, core.hold_current, _on(core.closed_loop), _on(core.stallguard),
            core.stall.sensitivity))
        write("bus  transactions %d  rejects %d  deadman %d ms  log %s" % (
            core.transactions, core.rejects, cfg.deadman_ms, L.LEVEL_NAMES[core.log.level]))
        if cfg.valid:
            s = cfg.stall
            write("stall  spike limit %g usteps  lowpass K %g Ts %g s tau %g s  threshold x%g, "
                  "+%g for %g..%g rad/s, slope %g" % (s.spike_limit, s.gain, s.sample_time,
                                                      s.time_constant, s.sensitivity_scale,
                                                      s.window_offset, s.window_low, s.window_high,
                                                      s.slope))

    def _regs(self, args):
        for addr in range(256):
            data = self.core.cached_reply(addr)
            if data is None:
                continue
            regs = self.core.registers
            raw = " ".join("%02x" % b for b in data)
            self._write("0x%02x %-14s %-18s %s" % (addr, regs.name(addr), raw, regs.decode(addr, bytes(data))))

    def _trace_cmd(self, args):
        if args == ["on"]:
            self.core.trace = self._trace_sample
            self._write("trace on: %s (one line per stall-detection sample, while stall detection runs)"
                        % " ".join(TRACE_COLUMNS))
        elif args == ["off"]:
            self.core.trace = None
            self._write("trace off")
        else:
            self._write("error: use trace on or trace off")

    def _trace_sample(self, s):
        self._write("%.2f\t%.2f\t%.2f\t%.3f\t%.3f\t%.2f\t%d" % (
            s.raw, s.despiked, s.filtered, s.speed, s.set_speed, s.threshold, s.stalled))

    def _log(self, args):
        names = L.LEVEL_NAMES
        level = args[0].upper() if len(args) == 1 else ""
        if level not in names:
            self._write("error: use log %s" % "|".join(names))
            return
        self.core.log.level = names.index(level)
        self._write("log level %s" % level)


def _yes(value):
    return "yes" if value else "no"


def _on(value):
    return "on" if value else "off"
