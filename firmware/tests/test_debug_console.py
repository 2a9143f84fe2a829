"""The joint's serial debug console: commands, trace, bounded work per main-loop call."""

from joint.console import log as L
from joint.console.debug_commands import TRACE_COLUMNS
from joint.console.debug import DebugConsole
from harness import Rig


class Keyboard:
    """Bytes typed on the serial port, handed out as a non-blocking reader would."""

    def __init__(self):
        self.waiting = b""
        self.reads = 0

    def type(self, text):
        self.waiting += text.encode()

    def read(self, buf):
        self.reads += 1
        n = min(len(buf), len(self.waiting))
        for i in range(n):
            buf[i] = self.waiting[i]
        self.waiting = self.waiting[n:]
        return n


class Console:
    def __init__(self):
        self.rig = Rig()
        self.keys = Keyboard()
        self.out = []
        self.debug = DebugConsole(self.rig.core, self.keys.read, self._write)

    def _write(self, line):
        self.out.append(line if isinstance(line, str) else bytes(line).decode())  # a trace line's buffer is reused

    def run(self, text, polls=20):
        self.keys.type(text)
        for _ in range(polls):
            self.debug.poll()
        out, self.out[:] = list(self.out), []
        return out


def test_status_reports_flags_setpoints_motion_and_configuration():
    console = Console()
    out = "\n".join(console.run("status\n"))
    assert "J1 at 0x11" in out and "NOTHOMED|NOTENABLED" in out
    assert "setpoints" in out and "motor  position" in out and "velocity" in out
    assert "deadman 50 ms" in out and "spike limit 100" in out


def test_regs_dumps_the_reply_caches():
    console = Console()
    lines = console.run("regs\r\n")
    ping = [line for line in lines if "PING" in line]
    assert len(ping) == 1 and "4f" in ping[0] and "(79,)" in ping[0]
    assert any("ANGLEMOVED" in line for line in lines)
    assert any("IDENTITY" in line for line in lines)


def test_trace_streams_every_stall_detection_sample():
    console = Console()
    rig = console.rig
    rig.command("SETUP", 20, 20, 0, 0)
    rig.command("ENABLESTALLGUARD", 5)
    assert console.run("trace on\n")[0].startswith("trace on: " + " ".join(TRACE_COLUMNS))
    rig.motor.error = 12  # usteps: the HAL reports whole usteps
    rig.run_ms(100)
    samples = [line.split("\t") for line in console.out]
    assert 9 <= len(samples) <= 11, "one sample per 10 ms"
    assert all(len(s) == len(TRACE_COLUMNS) for s in samples)
    assert samples[-1][0] == "12.00" and samples[-1][-1] == "0"
    assert float(samples[-1][5]) == 50.0, "threshold = sensitivity x 10 at standstill"
    console.out[:] = []
    assert console.run("trace off\n") == ["trace off"]
    rig.run_ms(100)
    assert console.out == []


def test_sampling_keeps_its_period_while_a_host_streams_a_command_every_millisecond():
    console = Console()
    rig = console.rig
    rig.command("SETUP", 20, 20, 0, 0)
    rig.command("ENABLESTALLGUARD", 5)
    console.run("trace on\n")
    for i in range(1000):
        rig.command("SETRPM", 30.0 + (i & 1))  # each one applied in the next iteration
        rig.run_ms(1)
    assert 99 <= len(console.out) <= 101, "%d samples in 1 s: the detector's filter assumes 10 ms" % len(console.out)


def test_trace_on_says_when_the_joint_runs_a_detector_without_a_trace():
    console = Console()
    console.rig.core.set_stall_detector("tracking")
    out = console.run("trace on\n")
    assert out[1] == "note: only the original stall detector is traced; this joint runs the tracking one"
    console.rig.core.set_stall_detector("original")
    assert len(console.run("trace on\n")) == 1


def test_log_level_changes_and_bad_levels_change_nothing():
    console = Console()
    assert console.run("log debug\n") == ["log level DEBUG"]
    assert console.rig.core.log.level == L.DEBUG
    assert console.run("log loud\n")[0].startswith("error: use log ERROR|WARN|INFO|DEBUG")
    assert console.run("log\n")[0].startswith("error")
    assert console.rig.core.log.level == L.DEBUG


def test_unknown_commands_long_lines_and_help():
    console = Console()
    assert console.run("jump\n") == ["error: unknown command 'jump'; type help"]
    assert console.run("x" * 200 + "\n")[0].startswith("error: line longer than")
    assert console.run("trace sideways\n") == ["error: use trace on or trace off"]
    assert len(console.run("help\n")) >= 4
    assert console.run("\n\r\n   \n") == []


def test_one_command_per_call_and_a_bounded_read():
    console = Console()
    console.keys.type("log warn\nlog error\nlog info\n")
    console.debug.poll()
    assert console.out == ["log level WARN"] and console.keys.reads == 1
    for _ in range(10):
        console.debug.poll()
    assert console.out == ["log level WARN", "log level ERROR", "log level INFO"]
    reads = console.keys.reads
    console.debug.poll()
    assert console.keys.reads == reads + 1, "an idle poll asks the reader once and returns"


def test_commands_split_across_reads_are_assembled():
    console = Console()
    for part in ("sta", "tu", "s\n"):
        console.keys.type(part)
        console.debug.poll()
    assert console.out and console.out[0].startswith("J1 at 0x11")


def test_bytes_that_are_not_text_get_an_error_not_an_exception():
    console = Console()
    console.keys.waiting = b"st\xffatus\n"
    for _ in range(5):
        console.debug.poll()
    assert console.out == ["error: not a text command"]
    console.out[:] = []
    assert console.run("log DEBUG\n") == ["log level DEBUG"], "the console still works"
