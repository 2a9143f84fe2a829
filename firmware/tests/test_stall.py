"""The original stall detector (stall.h): spike rejection, first-order low-pass, speed-adaptive
threshold, computed in small-int fixed point."""

from joint.config import schema as config
from joint.detect.stall import StallDetector


def _detector(sensitivity, **stall):
    cfg = config.default().stall
    for key, value in stall.items():
        setattr(cfg, key, value)
    det = StallDetector(cfg)
    det.sensitivity = sensitivity
    return det


def test_the_filter_is_first_order_like_the_original_lowpass():
    det = _detector(255)  # a threshold no step of 100 usteps reaches
    values = []
    for _ in range(10):
        det.update(100, 0, 0)
        values.append(det.filtered)
    assert abs(values[0] - 10.0) < 0.01 and abs(values[1] - 19.0) < 0.01
    assert abs(values[-1] - 100.0 * (1 - 0.9 ** 10)) < 0.05
    det.reset()
    det.update(0, 0, 0)
    assert det.filtered == 0.0


def test_the_filter_gain_scales_the_steady_state():
    det = _detector(255, gain=2.0)
    for _ in range(500):
        det.update(5, 0, 0)
    assert abs(det.filtered - 10.0) < 0.1


def test_threshold_adds_the_window_offset_only_inside_the_speed_window():
    det = _detector(6)
    assert det.threshold_at(0.0) == 60.0
    assert det.threshold_at(11.9) == 60.0
    assert det.threshold_at(12.0) == 150.0
    assert det.threshold_at(-450.0) == 150.0
    assert det.threshold_at(451.0) == 60.0


def test_spikes_are_rejected_against_the_last_accepted_sample():
    det = _detector(6)
    det.update(10, 0, 0)
    det.update(500, 0, 0)
    assert det.despiked == 10.0 and det.raw == 500.0
    det.update(-80, 0, 0)
    assert det.despiked == 80.0, "|error|, a 70 rise is accepted"


def test_stall_fires_when_filtered_error_exceeds_threshold_then_resets():
    det = _detector(6)
    fired_at = None
    for i in range(100):
        if det.update(65 if i < 1 else min(65 + i, 80), 0, 0):
            fired_at = i
            break
    assert fired_at is not None and fired_at > 5, "the low-pass delays detection"
    assert det.filtered > 60.0 and det.stalled
    assert det.last == 0.0
    det.update(0, 0, 0)
    assert det.filtered == 0.0, "filter state was cleared"


def test_speed_is_converted_from_rpm_to_rad_per_second():
    det = _detector(6)
    det.update(0, round(9.549296596425384 * 20 * 65536), 0)  # rpm in Q16, the HAL's unit
    assert abs(det.speed - 20.0) < 1e-3 and det.threshold == 150.0
