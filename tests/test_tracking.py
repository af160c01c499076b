"""The steady tracking offset (companion/guidance/tracking.py): reported once when the
vehicle rests farther from its target than the envelope's margin (issue 31 item 4)."""

from __future__ import annotations

import numpy as np

from companion.guidance.tracking import TrackingMonitor

TARGET = (5.0, 0.0, -7.0)


def _hover(monitor: TrackingMonitor, offset_m: float, seconds: float, t0: float = 0.0):
    pos = np.add(TARGET, (offset_m, 0.0, 0.0))
    reports = []
    for k in range(round(seconds * 30)):
        r = monitor.update(t0 + k / 30, pos, (0.0, 0.0, 0.0), TARGET)
        if r is not None:
            reports.append(r)
    return reports


def test_an_offset_beyond_the_margin_at_rest_is_reported_once_after_the_settle_time():
    m = TrackingMonitor(0.3, settle_s=2.0)
    assert _hover(m, 0.45, 1.9) == []  # not settled yet
    reports = _hover(m, 0.45, 5.0, t0=1.9)
    assert len(reports) == 1
    assert abs(reports[0].offset_m - 0.45) < 1e-12
    assert reports[0].target_ned_m == TARGET
    assert abs(m.offset_m - 0.45) < 1e-12


def test_within_the_margin_or_moving_nothing_is_said():
    m = TrackingMonitor(0.3)
    assert _hover(m, 0.25, 10.0) == []
    moving = TrackingMonitor(0.3)
    for k in range(300):
        assert moving.update(k / 30, (0.0, 0.0, -7.0), (0.5, 0.0, 0.0), TARGET) is None
    # a target that keeps moving never settles
    m2 = TrackingMonitor(0.3)
    for k in range(300):
        target = (5.0 + 0.1 * k, 0.0, -7.0)
        assert m2.update(k / 30, (0.0, 0.0, -7.0), (0.0, 0.0, 0.0), target) is None


def test_hysteresis_reports_again_only_after_coming_back_under_half_the_margin():
    m = TrackingMonitor(0.3, settle_s=1.0)
    assert len(_hover(m, 0.5, 3.0)) == 1
    assert _hover(m, 0.2, 3.0, t0=3.0) == []  # better, but not under half: still latched
    assert _hover(m, 0.1, 3.0, t0=6.0) == []  # re-armed
    assert len(_hover(m, 0.5, 3.0, t0=9.0)) == 1


def test_bad_input_is_no_report():
    m = TrackingMonitor(0.3)
    assert m.update(0.0, (np.nan, 0.0, 0.0), (0.0, 0.0, 0.0), TARGET) is None
    assert m.update(0.1, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), None) is None
