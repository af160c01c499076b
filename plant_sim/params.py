"""Quadrotor and flight-control parameters: Table 2 and Eq. (29)–(33) of Park & Kim.

Everything the paper gives is reproduced exactly; everything it does not give is a named
assumption with a unit and a one-line justification. Both dataclasses are frozen; build
them from a mapping with :func:`from_dict`, which rejects unknown names.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, TypeVar

from protocols.config import (
    ConfigError,
    UnknownKeyError,
    bounded,
    check_fields,
    dataclass_from_mapping,
)

__all__ = [
    "ControlParams",
    "QuadrotorParams",
    "UnknownParameterError",
    "from_dict",
]

_G_MPS2 = 9.81


#: a configuration mapping named a parameter that does not exist (also a TypeError)
UnknownParameterError = UnknownKeyError


@dataclass(frozen=True)
class QuadrotorParams:
    """Rigid-body, aerodynamic and rotor parameters (paper Table 2 + stated assumptions)."""

    # --- Table 2 ---------------------------------------------------------------------
    mass_kg: float = bounded(0.65, "kg", gt=0)
    inertia_kgm2: tuple[float, float, float] = (7.5e-3, 7.5e-3, 1.3e-2)  # J = diag(Jx, Jy, Jz)
    arm_length_m: float = bounded(0.25, "m", gt=0)  # d: centre of mass to rotor axis
    drag_force_kgps: tuple[float, float, float] = (2.0, 2.0, 4.0)  # K_t = diag(ktx, kty, ktz)
    drag_torque_kgm2ps: tuple[float, float, float] = (0.15, 0.15, 0.15)  # K_r
    gravity_mps2: float = bounded(_G_MPS2, "m/s²", gt=0)  # |G|

    # --- Assumptions (not in the paper) ------------------------------------------------
    # T_i = c·F_i in Eq. (14). 0.016 m is typical of 8–10" props (k_m/k_f ≈ 0.01–0.02 m).
    rotor_torque_coeff_m: float = bounded(0.016, "m", gt=0)
    # Per-rotor thrust ceiling: thrust-to-weight 2.0, the usual minimum for a camera quad.
    rotor_thrust_max_n: float = bounded(2.0 * 0.65 * _G_MPS2 / 4.0, "N", gt=0)
    # Rotors cannot pull: fixed-pitch props produce no negative thrust.
    rotor_thrust_min_n: float = bounded(0.0, "N", ge=0)
    # Vehicle sphere used by collision checks: arm length plus a propeller radius of 0.1 m.
    body_radius_m: float = bounded(0.35, "m", gt=0)

    def __post_init__(self) -> None:
        check_fields(self)
        for name in ("inertia_kgm2", "drag_force_kgps", "drag_torque_kgm2ps"):
            value = getattr(self, name)
            if len(value) != 3:
                raise ValueError(f"{name} needs 3 values, got {len(value)}")
            object.__setattr__(self, name, tuple(float(v) for v in value))
            for v in getattr(self, name):
                _require_positive(name, v, allow_zero=name != "inertia_kgm2")
        if not self.rotor_thrust_min_n < self.rotor_thrust_max_n:
            raise ConfigError(
                f"must be below rotor_thrust_max_n {self.rotor_thrust_max_n}, got "
                f"{self.rotor_thrust_min_n}",
                key="rotor_thrust_min_n",
            )
        if 4.0 * self.rotor_thrust_max_n <= self.mass_kg * self.gravity_mps2:
            raise ConfigError(
                "4 × rotor_thrust_max_n must exceed the weight m·g to fly",
                key="rotor_thrust_max_n",
            )

    @property
    def hover_thrust_n(self) -> float:
        """Total thrust that balances gravity, m·g [N]."""
        return self.mass_kg * self.gravity_mps2


@dataclass(frozen=True)
class ControlParams:
    """LQ weights (Eq. 29, 30, 32, 33), limits and loop rates of the flight controller."""

    # --- Paper ----------------------------------------------------------------------------
    # Attitude subsystem, state [φ, φ̇, θ, θ̇, ψ, ψ̇]: Eq. (29), (30).
    q_attitude: tuple[float, ...] = (10.0, 6.0, 10.0, 6.0, 10.0, 6.0)
    r_attitude: tuple[float, float, float] = (0.1, 0.1, 0.1)
    # Position subsystem, state [x, ẋ, y, ẏ, z, ż]: Eq. (32), (33).
    q_position: tuple[float, ...] = (2.0, 9.0, 2.0, 9.0, 2.0, 9.0)
    r_position: tuple[float, float, float] = (1.0, 1.0, 1.0)
    # §6.1: desired roll and pitch within ±15°.
    max_tilt_deg: float = bounded(15.0, "deg", gt=0, lt=90)

    # --- Assumptions (not in the paper) ------------------------------------------------
    # RK4 step rate. 400 Hz is ArduCopter's main-loop rate; the attitude poles
    # (−1.3, −7.6 rad/s) are two orders below its Nyquist rate.
    physics_rate_hz: float = bounded(400.0, "Hz", gt=0)
    # Controller update rate (zero-order hold between updates); must divide physics_rate_hz.
    control_rate_hz: float = bounded(400.0, "Hz", gt=0)
    # Lowest vertical specific force the position loop may ask of the rotors [m/s²]
    # (a fraction of g): keeps φ_d, θ_d defined when a steep descent is commanded.
    min_vertical_accel_mps2: float = bounded(0.2 * _G_MPS2, "m/s²", gt=0)

    def __post_init__(self) -> None:
        check_fields(self)
        for name, n in (
            ("q_attitude", 6),
            ("r_attitude", 3),
            ("q_position", 6),
            ("r_position", 3),
        ):
            value = tuple(float(v) for v in getattr(self, name))
            if len(value) != n:
                raise ValueError(f"{name} needs {n} values, got {len(value)}")
            if any(not math.isfinite(v) or v < 0.0 for v in value):
                raise ValueError(f"{name} must be finite and non-negative, got {value}")
            object.__setattr__(self, name, value)
        if any(v <= 0.0 for v in self.r_attitude + self.r_position):
            raise ValueError("LQ input weights R must be positive definite")
        ratio = self.physics_rate_hz / self.control_rate_hz
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise ConfigError(
                f"must divide physics_rate_hz ({self.physics_rate_hz}), got {self.control_rate_hz}",
                key="control_rate_hz",
            )

    @property
    def physics_dt_s(self) -> float:
        """Fixed RK4 step [s]."""
        return 1.0 / self.physics_rate_hz

    @property
    def steps_per_control(self) -> int:
        """Physics steps per controller update."""
        return round(self.physics_rate_hz / self.control_rate_hz)


_P = TypeVar("_P", QuadrotorParams, ControlParams)


def from_dict(cls: type[_P], values: Mapping[str, Any]) -> _P:
    """Build a parameter dataclass from a mapping, rejecting unknown names.

    Raises
    ------
    UnknownParameterError
        If ``values`` names a field ``cls`` does not have; the message lists the
        unknown names and the valid ones.
    """
    return dataclass_from_mapping(cls, values, cls.__name__)


def _require_positive(name: str, value: float, *, allow_zero: bool = False) -> None:
    ok = value >= 0.0 if allow_zero else value > 0.0
    if not (math.isfinite(value) and ok):
        bound = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name} must be finite and {bound}, got {value}")
