"""LQ tracker design: gains of Eq. (31) and (34) computed with control.lqr."""

import math

import numpy as np
import pytest

from plant_sim.lq import design_tracker
from plant_sim.params import ControlParams


def _closed_form_gain(q_pos: float, q_rate: float, r: float) -> tuple[float, float]:
    """LQR gain of a double integrator: k1 = √(q1/r), k2 = √((q2 + 2√(q1 r))/r)."""
    return math.sqrt(q_pos / r), math.sqrt((q_rate + 2.0 * math.sqrt(q_pos * r)) / r)


def test_attitude_gains_equal_eq31():
    c = ControlParams()
    gains = design_tracker(c.q_attitude, c.r_attitude).per_axis_gains()
    for k_angle, k_rate in gains:
        assert round(k_angle, 1) == 10.0  # Eq. (31) prints 10.0
        assert round(k_rate, 2) == 8.94  # and 8.94
        np.testing.assert_allclose((k_angle, k_rate), _closed_form_gain(10, 6, 0.1), rtol=1e-9)


def test_position_gains_equal_eq34():
    c = ControlParams()
    gains = design_tracker(c.q_position, c.r_position).per_axis_gains()
    for k_pos, k_rate in gains:
        assert round(k_pos, 1) == 1.4  # Eq. (34) prints 1.4
        assert round(k_rate, 2) == 3.44  # and 3.44
        np.testing.assert_allclose((k_pos, k_rate), _closed_form_gain(2, 9, 1), rtol=1e-9)


@pytest.mark.parametrize("which", ["attitude", "position"])
def test_closed_loop_is_stable_and_decoupled(which):
    c = ControlParams()
    t = design_tracker(getattr(c, f"q_{which}"), getattr(c, f"r_{which}"))
    assert np.all(np.real(t.closed_loop_poles) < 0)
    eig = np.linalg.eigvals(t.A - t.B @ t.K)
    np.testing.assert_allclose(np.sort(eig.real), np.sort(t.closed_loop_poles.real), atol=1e-9)
    t.per_axis_gains()  # raises if K couples the axes


def test_reference_of_eq23_is_position_with_zero_rate_and_input():
    """Eq. (23) for double integrators: x_d = [y_d, 0], u_d = 0 (what the kernels assume)."""
    c = ControlParams()
    t = design_tracker(c.q_position, c.r_position)
    y_d = np.array([3.0, -2.0, 7.0])
    np.testing.assert_allclose(t.x_d_from_y_d @ y_d, [3, 0, -2, 0, 7, 0], atol=1e-12)
    np.testing.assert_allclose(t.u_d_from_y_d @ y_d, 0.0, atol=1e-12)
    # Eq. (22): at x = x_d the input vanishes; a unit position error gives −k1
    x = np.array([4.0, 0, -2, 0, 7, 0])
    np.testing.assert_allclose(t.input(x, y_d), [-t.K[0, 0], 0, 0], atol=1e-12)
