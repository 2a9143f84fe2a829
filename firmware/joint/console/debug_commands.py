"""The debug console's commands (see debug.py): imported by the console's first complete line, so
a joint nobody types to keeps only the line reader."""

from . import log as L
from ..motion.fixed import ANGLE_Q, RPM_Q
from ..core.supervise import DETECTOR_NAMES, ORIGINAL
from ..detect.trace_line import TraceLine

TRACE_COLUMNS = ("raw", "despiked", "filtered", "speed", "set_speed", "threshold", "stall")
TRACE_UNITS = ("usteps", "usteps", "usteps", "rad/s", "rad/s", "usteps", "")
HELP = (
    "status        flags, setpoints, position, velocity, configuration",
    "regs          register reply caches",
    "trace on|off  stall-detection samples: " + " ".join(TRACE_COLUMNS),
    "log LEVEL     ERROR, WARN, INFO or DEBUG",
)
_ANGLE = 1 << ANGLE_Q
_RPM = 1 << RPM_Q


class Commands:
    """Runs one console command on `core`; `write(line)` prints a line (see DebugConsole)."""

    def __init__(self, core, write):
        self.core = core
        self._write = write
        self._trace_line = None  # made by the first `trace on`: its buffers take ~2 KB
        self._commands = {"status": self._status, "regs": self._regs, "trace": self._trace_cmd,
                          "log": self._log, "help": self._help}

    def execute(self, name, args):
        command = self._commands.get(name)
        if command is None:
            self._write("error: unknown command %r; type help" % name)
        else:
            command(args)

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
            core.transactions, core.reject_count(), cfg.deadman_ms, L.LEVEL_NAMES[core.log.level]))
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
            if self._trace_line is None:
                self._trace_line = TraceLine()
            self.core.trace = self._trace_sample
            self._write("trace on: %s (one line per stall-detection sample, while stall detection runs)"
                        % " ".join(TRACE_COLUMNS))
            if self.core.detector != ORIGINAL:
                self._write("note: only the original stall detector is traced; this joint runs the %s one"
                            % DETECTOR_NAMES[self.core.detector])
        elif args == ["off"]:
            self.core.trace = None
            self._write("trace off")
        else:
            self._write("error: use trace on or trace off")

    def _trace_sample(self, s):
        self._write(self._trace_line.line(s))

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
