"""Wind, gusts and a wandering estimate (issue 31 item 4) against closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from plant_sim.autopilot.integrator import VelocityIntegrator
from plant_sim.disturbance import DisturbanceConfig, Disturbances, EstimateConfig, WindConfig
from plant_sim.params import QuadrotorParams
from plant_sim.vehicle import Quadrotor, Setpoint


def test_steady_wind_leaves_the_lq_loops_closed_form_offset():
    """Drag on the air-relative velocity; the controller's FL cancels the drag of the
    ground velocity only, so a steady wind w is a constant acceleration K_t w / m that the
    position loop (no integrator) balances at an offset K_t w / (m k_p) downwind."""
    wind_n = 0.3
    q = Quadrotor(pos_ned_m=(0.0, 0.0, -7.0), yaw_rad=0.0)
    q.set_wind_ned_mps((wind_n, 0.0, 0.0))
    q.run_until(60.0)
    p = QuadrotorParams()
    k_p = float(q._gains_pos[0, 0])
    expected = p.drag_force_kgps[0] * wind_n / (p.mass_kg * k_p)
    assert q.pos_ned_m[0] == pytest.approx(expected, rel=0.02), (q.pos_ned_m, expected, k_p)
    assert abs(q.pos_ned_m[1]) < 1e-9
    np.testing.assert_allclose(q.vel_ned_mps, 0.0, atol=1e-6)


def _closed_loop_poles(k_p: float, k_d: float, k_i: float) -> np.ndarray:
    """Per-axis poles of the LQ loop with the velocity integrator (attitude lag neglected):
    s³ + k_d s² + (k_p + k_i) s + k_i k_p / k_d (plant_sim.flight_control)."""
    return np.roots([1.0, k_d, k_p + k_i, k_i * k_p / k_d])


def test_arducopters_velocity_integrator_removes_the_wind_offset_at_its_time_constant():
    """PSC_VELXY_I at its default (1.0): the integrator's sum settles at the wind's
    uncancelled drag −K_t w / m, and the offset decays with the slowest closed-loop pole,
    from the paper loop's K_t w / (m k_p) ≈ 0.33 m at 0.15 m/s to under 2 cm in 5 time
    constants (the same airframe and wind without it keeps the offset: test above)."""
    wind_n = 0.15
    q = Quadrotor(pos_ned_m=(0.0, 0.0, -7.0), yaw_rad=0.0)
    integrator = VelocityIntegrator()
    assert (integrator.gain_xy_per_s2, integrator.imax_xy_mps2) == (1.0, 10.0)  # ArduCopter
    integrator.apply_to(q)
    q.set_wind_ned_mps((wind_n, 0.0, 0.0))
    p = QuadrotorParams()
    k_p, k_d = (float(g) for g in q._gains_pos[0])
    drag_per_s = p.drag_force_kgps[0] / p.mass_kg
    offset_without_m = drag_per_s * wind_n / k_p
    assert offset_without_m == pytest.approx(0.33, abs=0.01)
    poles = _closed_loop_poles(k_p, k_d, integrator.gain_xy_per_s2)
    assert np.all(poles.real < 0)
    tau_s = 1.0 / float(np.min(np.abs(poles.real)))  # 3.9 s with the paper's gains
    peak = 0.0
    while q.time_s < 5.0 * tau_s:
        q.run_until(q.time_s + 0.1)
        peak = max(peak, abs(float(q.pos_ned_m[0])))
    assert peak < offset_without_m  # never worse than the paper loop's steady offset
    assert abs(float(q.pos_ned_m[0])) < 0.05 * offset_without_m  # < e^-3 after 5 τ
    q.run_until(q.time_s + 5.0 * tau_s)
    assert abs(float(q.pos_ned_m[0])) < 1e-3
    np.testing.assert_allclose(
        q.velocity_integrator_ned_mps2, (-drag_per_s * wind_n, 0.0, 0.0), atol=2e-3
    )


def test_the_integrator_is_limited_to_imax_and_off_on_the_ground():
    q = Quadrotor(pos_ned_m=(0.0, 0.0, -7.0), yaw_rad=0.0)
    q.set_velocity_integrator(1.0, 0.2)  # below the 0.46 m/s² a 0.15 m/s wind asks for
    q.set_wind_ned_mps((0.15, 0.0, 0.0))
    q.run_until(40.0)
    assert np.linalg.norm(q.velocity_integrator_ned_mps2) == pytest.approx(0.2, abs=1e-9)
    p = QuadrotorParams()
    k_p = float(q._gains_pos[0, 0])
    residual = (p.drag_force_kgps[0] / p.mass_kg * 0.15 - 0.2) / k_p  # what IMAX leaves
    assert q.pos_ned_m[0] == pytest.approx(residual, rel=0.02)
    q.set_armed(False)
    q.step(10)
    assert not np.any(q.velocity_integrator_ned_mps2)
    with pytest.raises(ValueError):
        q.set_velocity_integrator(math.nan, 1.0)


def test_the_integrator_holds_while_the_reference_accelerates():
    """The paper's slow tilt loop trails an accelerating reference; the sum must not wind
    up on that lag (plant_sim.flight_control._I_HOLD_ACCEL_MPS2), only on what stays."""
    q = Quadrotor(pos_ned_m=(0.0, 0.0, -7.0), yaw_rad=0.0)
    VelocityIntegrator().apply_to(q)
    accel = 1.0  # a reference speeding up at 1 m/s² northward, for 2 s
    for i in range(100):
        t = 0.02 * i
        q.set_setpoint(
            Setpoint(
                pos_ned_m=(0.5 * accel * t * t, 0.0, -7.0),
                vel_ned_mps=(accel * t, 0.0, 0.0),
                acc_ned_mps2=(accel, 0.0, 0.0),
                yaw_rad=0.0,
            )
        )
        q.run_until(t + 0.02)
    assert not np.any(q.velocity_integrator_ned_mps2)
    # it trailed the 2 m/s reference by more than 0.5 m/s: there was lag to integrate
    assert 0.0 < q.vel_ned_mps[0] < 2.0 * accel - 0.5


def test_still_air_is_the_papers_model_bit_for_bit():
    a = Quadrotor(pos_ned_m=(20.0, 0.0, -7.0), yaw_rad=math.pi)
    b = Quadrotor(pos_ned_m=(20.0, 0.0, -7.0), yaw_rad=math.pi)
    b.set_wind_ned_mps((0.0, 0.0, 0.0))
    for q in (a, b):
        q.set_setpoint(type(q.setpoint)(pos_ned_m=(15.0, 1.0, -8.0), yaw_rad=math.pi))
        q.run_until(5.0)
    assert np.array_equal(a.snapshot().pos_ned_m, b.snapshot().pos_ned_m)


def test_gusts_and_wander_have_their_stationary_statistics():
    """Gauss-Markov: stationary standard deviation σ, autocorrelation e^(−Δt/τ)."""
    cfg = DisturbanceConfig(
        wind=WindConfig(mean_ned_mps=(1.0, -0.5, 0.0), gust_std_mps=0.4, gust_tau_s=2.0),
        estimate=EstimateConfig(wander_std_m=0.3, wander_tau_s=5.0),
        seed=3,
    )
    d = Disturbances(cfg)
    winds, errors = [], []
    for i in range(1, 20_001):  # 4000 s at 0.2 s
        d.advance(0.2 * i)
        winds.append(d.wind_ned_mps)
        errors.append(d.estimate_error_ned_m)
    w, e = np.array(winds), np.array(errors)
    # 2000 gust correlation times: the sample mean and deviation within a few percent
    np.testing.assert_allclose(w.mean(axis=0)[:2], (1.0, -0.5), atol=0.05)
    np.testing.assert_allclose(w[:, :2].std(axis=0), 0.4, rtol=0.08)
    assert np.all(w[:, 2] == 0.0)  # no vertical gusts asked for
    np.testing.assert_allclose(e[:, :2].std(axis=0), 0.3, rtol=0.15)  # 800 τ
    g = w[:, 0] - w[:, 0].mean()
    lag = 10  # 2 s = τ
    rho = float(np.dot(g[:-lag], g[lag:]) / np.dot(g, g))
    assert rho == pytest.approx(math.exp(-1.0), abs=0.06)


def test_drift_grows_linearly_and_jumps_come_at_their_rate():
    drift = DisturbanceConfig(estimate=EstimateConfig(drift_ned_mps=(0.01, 0.0, 0.0)))
    d = Disturbances(drift)
    d.advance(100.0)
    np.testing.assert_allclose(d.estimate_error_ned_m, (1.0, 0.0, 0.0), atol=1e-9)
    jumps = DisturbanceConfig(estimate=EstimateConfig(jump_m=0.8, jump_every_s=10.0), seed=1)
    d = Disturbances(jumps)
    before = np.zeros(3)
    sizes = []
    for i in range(1, 200_001):  # 4000 s
        d.advance(0.02 * i)
        now = np.array(d.estimate_error_ned_m)
        step = np.linalg.norm(now - before)
        if step > 0.4:  # between jumps the error only decays (wander τ 30 s: ~1 mm a step)
            sizes.append(step)
        assert now[2] == 0.0  # horizontal
        before = now
    # Poisson: 400 expected, standard deviation 20
    assert abs(d.jumps - 400) < 4 * 20, d.jumps
    assert len(sizes) == d.jumps
    np.testing.assert_allclose(sizes, 0.8, rtol=0.01)


def test_the_same_seed_gives_the_same_flight():
    cfg = DisturbanceConfig(wind=WindConfig(gust_std_mps=0.2), seed=9)
    a, b = Disturbances(cfg), Disturbances(cfg)
    for t in (0.5, 1.0, 7.3):
        a.advance(t)
        b.advance(t)
    assert a.wind_ned_mps == b.wind_ned_mps
    assert not DisturbanceConfig(seed=4).active and cfg.active


@pytest.mark.parametrize(
    ("kwargs", "says"),
    [
        ({"wind": WindConfig(gust_std_mps=-1.0)}, "gust_std_mps"),
        ({"wind": WindConfig(gust_tau_s=0.0)}, "gust_tau_s"),
        ({"estimate": EstimateConfig(wander_std_m=math.nan)}, "wander_std_m"),
        ({"estimate": EstimateConfig(jump_every_s=0.0)}, "jump_every_s"),
        ({"wind": WindConfig(mean_ned_mps=(1.0, math.inf, 0.0))}, "mean_ned_mps"),
        ({"seed": -1}, "seed"),
    ],
)
def test_a_bad_disturbance_is_refused_by_name(kwargs, says):
    with pytest.raises(ValueError, match=says):
        DisturbanceConfig(**kwargs)
