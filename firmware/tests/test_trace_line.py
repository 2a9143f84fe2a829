"""The console's trace line (trace_line.py): the original's `%.2f`/`%.3f` columns, written from the
stall detector's fixed-point ints into a reused buffer."""

from joint.config import schema as config
from joint.console.debug_commands import TRACE_COLUMNS
from joint.detect.stall import StallDetector
from joint.detect.trace_line import TraceLine

_RPM = 65536  # rpm Q16, as the HAL gives speeds
_DECIMALS = (2, 2, 2, 3, 3, 2, 0)


def _detector():
    det = StallDetector(config.default().stall)
    det.sensitivity = 6
    return det


def _fields(view):
    return bytes(view).decode().split("\t")


def _columns(det):
    return (det.raw, det.despiked, det.filtered, det.speed, det.set_speed, det.threshold, int(det.stalled))


def test_a_sample_reads_as_the_original_formatted_it():
    det = _detector()
    line = TraceLine()
    for error, rpm, set_rpm in ((12, 30, 30), (-40, -120, -125), (3, 0, 0), (900, 5, 60)):
        det.update(error, rpm * _RPM, set_rpm * _RPM)
        fields = _fields(line.line(det))
        assert len(fields) == len(TRACE_COLUMNS)
        for field, value, decimals in zip(fields, _columns(det), _DECIMALS):
            assert len(field.partition(".")[2]) == decimals, field
            # the same digits as "%.*f", up to how a half is rounded
            assert abs(float(field) - value) <= 0.5 * 10 ** -decimals + 1e-9, (field, value)
    det.update(12, 30 * _RPM, 30 * _RPM)
    assert _fields(line.line(det))[:2] == ["12.00", "12.00"]


def test_negative_speeds_and_large_errors_keep_their_sign_and_digits():
    det = _detector()
    det.update(-32767, -3000 * _RPM, -2500 * _RPM)
    fields = _fields(TraceLine().line(det))
    assert fields[0] == "32767.00", "raw is |PID error|"
    assert fields[3].startswith("-314.") and fields[4].startswith("-261."), fields
    assert fields[6] in ("0", "1")


def test_a_stall_prints_1_and_the_buffer_is_reused():
    det = _detector()
    line = TraceLine()
    for error in range(0, 5000, 10):  # rising slower than the spike limit
        if det.update(error, 0, 0):
            break
    assert det.stalled
    first = line.line(det)
    printed = bytes(first)
    assert _fields(first)[6] == "1"
    det.update(0, 0, 0)
    second = line.line(det)
    assert _fields(second)[6] == "0"
    assert bytes(first) != printed, "one buffer: a line is valid until the next"
