"""Issue 32: one latency budget, measured (companion.guidance.latency) and used by the envelope."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.guidance.config import GuidanceConfig
from companion.guidance.envelope import EnvelopeConfig, envelope_step, speed_limit_mps
from companion.guidance.latency import DataAgeWindow, nearest_rank_percentile
from companion.perception import PerceptionConfig

CFG = EnvelopeConfig()
MS = 1_000_000


def _window(**kw) -> DataAgeWindow:
    args = {
        "floor_s": CFG.latency_s,
        "window_s": CFG.latency_window_s,
        "percentile": CFG.latency_percentile,
        "unmeasured_s": CFG.unmeasured_latency_s,
    }
    args.update(kw)
    return DataAgeWindow(**args)


def _closed_form_limit(room_m: float, latency_s: float, accel_mps2: float) -> float:
    """v = a(−L + √(L² + 2·room/a)), the root of L·v + v²/(2a) = room."""
    return accel_mps2 * (-latency_s + math.sqrt(latency_s**2 + 2.0 * room_m / accel_mps2))


def test_nearest_rank_percentile_of_a_known_window():
    ages = [k / 100.0 for k in range(1, 101)]  # 0.01 .. 1.00 s
    assert nearest_rank_percentile(ages, 95.0) == pytest.approx(0.95)
    assert nearest_rank_percentile(ages, 50.0) == pytest.approx(0.50)
    assert nearest_rank_percentile(ages, 100.0) == pytest.approx(1.00)
    assert math.isnan(nearest_rank_percentile([], 95.0))
    # 20 samples: rank ceil(0.95 · 20) = 19
    twenty = sorted([0.03] * 18 + [0.4, 0.9])
    assert nearest_rank_percentile(twenty, 95.0) == pytest.approx(0.4)


def test_window_p95_budget_and_rate_from_frames_at_30_hz():
    w = _window()
    # 30 Hz for 2 s: ages 40 ms, except every 10th frame 300 ms (10 %)
    for k in range(60):
        w.add(k * 33 * MS, 0.3 if k % 10 == 9 else 0.04)
    stats = w.stats()
    assert stats.samples == 60
    assert stats.p50_s == pytest.approx(0.04)
    assert stats.budget_percentile_s == pytest.approx(0.3)  # 10 % > 5 %: p95 is a slow one
    assert stats.p99_s == pytest.approx(0.3)
    assert stats.rate_hz == pytest.approx(1e9 / (33 * MS), rel=1e-9)
    assert w.budget_s() == pytest.approx(0.3 + CFG.unmeasured_latency_s)


def test_budget_never_below_the_floor_and_counts_a_stalled_frame_at_once():
    w = _window()
    assert w.budget_s() == CFG.latency_s  # nothing measured: the configured constant
    for k in range(30):
        w.add(k * 33 * MS, 0.02)
    assert w.budget_s() == CFG.latency_s  # 0.02 + 0.1 < 0.15
    assert w.budget_s(current_age_s=0.5) == pytest.approx(0.5 + CFG.unmeasured_latency_s)


def test_window_forgets_frames_older_than_its_span():
    w = _window(window_s=2.0)
    w.add(0, 0.9)
    for k in range(1, 70):
        w.add(k * 33 * MS, 0.03)
    assert w.stats().samples < 70
    assert w.budget_s() == CFG.latency_s  # the slow frame at t = 0 is 2.3 s old


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_bad_ages_are_counted_not_raised(bad):
    w = _window()
    assert w.add(0, bad) is False
    assert w.rejected == 1 and len(w) == 0
    assert w.budget_s(current_age_s=bad) == CFG.latency_s


def test_negative_and_huge_ages_are_clamped_and_counted():
    w = _window(max_age_s=5.0)
    w.add(0, -0.2)  # a capture time in the future
    w.add(33 * MS, 1e9)
    w.add(10 * MS, 0.05)  # out of order
    assert w.clamped == 3
    assert w.percentile_s(100.0) == 5.0
    assert w.percentile_s(1.0) == 0.0


@pytest.mark.parametrize("room_m", [0.2, 1.0, 3.0, 7.7])
@pytest.mark.parametrize("latency_s", [0.15, 0.3, 0.6, 1.2])
def test_speed_limit_matches_the_closed_form_with_latency(room_m, latency_s):
    a = CFG.accel_mps2
    got = speed_limit_mps(room_m + CFG.margin_m, latency_s, a, CFG.margin_m)
    assert got == pytest.approx(_closed_form_limit(room_m, latency_s, a), rel=1e-12)


def _const_free(free_m):
    def free(pos, direction, radius_m, limit_m, half_height_m, body_m, near_field_m):
        return min(free_m, limit_m)

    return free


def _step(latency_s, speed_mps=2.0, free_m=6.0):
    return envelope_step(
        pos_ned_m=[20.0, 0.0, -7.0],
        vel_ned_mps=[-speed_mps, 0.0, 0.0],
        setpoint_ned_m=[0.0, 0.0, -7.0],
        free_distance=_const_free(free_m),
        vehicle_radius_m=PerceptionConfig().vehicle_radius_m,
        max_path_elevation_rad=GuidanceConfig().max_aim_elevation_rad,
        latency_s=latency_s,
    )


def test_speed_limit_and_carrot_shrink_smoothly_as_the_measured_age_grows():
    ages = np.linspace(0.0, 2.0, 81)
    outs = [_step(_window().budget_s(current_age_s=a)) for a in ages]
    limits = np.array([o.speed_limit_mps for o in outs])
    carrots = np.array([20.0 - o.setpoint_ned_m[0] for o in outs])
    assert np.all(np.diff(limits) <= 1e-12), limits  # monotone non-increasing
    assert np.all(np.diff(carrots) <= 1e-12), carrots
    assert limits[-1] < limits[0] and carrots[-1] < carrots[0]
    # smooth: no step between neighbouring ages larger than the slope bound allows
    # (dv/dτ = a(−1 + τ/√(τ²+2room/a)) ≥ −a; the ages are 25 ms apart)
    assert np.max(-np.diff(limits)) <= CFG.accel_mps2 * 0.025 + 1e-9
    # ages below the floor change nothing (τ = 0.15 s)
    assert outs[0].latency_s == CFG.latency_s
    # the closed form for each τ used
    room = 6.0 - CFG.margin_m
    for o in outs:
        expected = _closed_form_limit(room, o.latency_s, CFG.accel_mps2)
        assert o.speed_limit_mps == pytest.approx(expected, rel=1e-12)
    # still a positive speed at 2 s of data age: stopping only when no speed is safe
    assert limits[-1] > 0.0


def test_envelope_ignores_a_budget_below_the_floor_or_not_a_number():
    base = _step(None)
    for latency in (0.0, 0.1, math.nan, -1.0):
        out = _step(latency)
        assert out.latency_s == CFG.latency_s
        assert out.speed_limit_mps == base.speed_limit_mps


def test_config_bounds_of_the_latency_budget():
    with pytest.raises(ValueError, match="latency_percentile"):
        EnvelopeConfig(latency_percentile=30.0)
    with pytest.raises(ValueError, match="latency_window_s"):
        EnvelopeConfig(latency_window_s=0.0)
    with pytest.raises(ValueError, match="unmeasured_latency_s"):
        EnvelopeConfig(unmeasured_latency_s=2.0)
