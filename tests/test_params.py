"""Parameter dataclasses: Table 2 values, validation, unknown names."""

import dataclasses

import pytest

from plant_sim.params import ControlParams, QuadrotorParams, UnknownParameterError, from_dict


def test_table2_values():
    p = QuadrotorParams()
    assert p.mass_kg == 0.65
    assert p.inertia_kgm2 == (7.5e-3, 7.5e-3, 1.3e-2)
    assert p.arm_length_m == 0.25
    assert p.drag_force_kgps == (2.0, 2.0, 4.0)
    assert p.drag_torque_kgm2ps == (0.15, 0.15, 0.15)
    assert p.gravity_mps2 == 9.81
    assert p.hover_thrust_n == pytest.approx(0.65 * 9.81, rel=1e-15)


def test_paper_weights():
    c = ControlParams()
    assert c.q_attitude == (10, 6, 10, 6, 10, 6)
    assert c.r_attitude == (0.1, 0.1, 0.1)
    assert c.q_position == (2, 9, 2, 9, 2, 9)
    assert c.r_position == (1, 1, 1)
    assert c.max_tilt_deg == 15.0


def test_params_are_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        QuadrotorParams().mass_kg = 1.0  # type: ignore[misc]


@pytest.mark.parametrize("cls", [QuadrotorParams, ControlParams])
def test_unknown_parameter_names_the_key(cls):
    with pytest.raises(UnknownParameterError, match="masss_kg") as info:
        from_dict(cls, {"masss_kg": 1.0})
    assert "valid: [" in str(info.value)
    assert all(f.name in str(info.value) for f in dataclasses.fields(cls))


def test_from_dict_builds_known_keys():
    assert from_dict(QuadrotorParams, {"mass_kg": 1.2}).mass_kg == 1.2
    assert from_dict(ControlParams, {"physics_rate_hz": 800}).steps_per_control == 2


@pytest.mark.parametrize(
    ("cls", "kwargs", "match"),
    [
        (QuadrotorParams, {"mass_kg": -1.0}, "mass_kg"),
        (QuadrotorParams, {"mass_kg": float("nan")}, "mass_kg"),
        (QuadrotorParams, {"inertia_kgm2": (1.0, 1.0)}, "inertia_kgm2"),
        (QuadrotorParams, {"rotor_thrust_max_n": 1.0}, "weight"),
        (QuadrotorParams, {"rotor_thrust_min_n": 5.0}, "rotor_thrust_min_n"),
        (ControlParams, {"max_tilt_deg": 95.0}, "max_tilt_deg"),
        (ControlParams, {"r_position": (1.0, 0.0, 1.0)}, "positive definite"),
        (ControlParams, {"control_rate_hz": 300.0}, "divide"),
    ],
)
def test_invalid_values_are_clear_errors(cls, kwargs, match):
    with pytest.raises(ValueError, match=match):
        cls(**kwargs)
