"""Vehicle profiles: named sets of airframe and controller parameters for plant-sim.

* ``paper`` (default) — Table 2 exactly, ±15° tilt (§6.1): drag-limited to
  ``m·g·tan 15° / k_t = 0.85 m/s``.
* ``fast`` — a racing-size camera quad, so the safety envelope is exercised at the speeds a
  real autopilot flies a far position target (ArduCopter's WPNAV_SPEED defaults to
  10 m/s): translational drag ``k_t = (0.3, 0.3, 0.6) kg/s`` (a streamlined 0.65 kg
  airframe), ±35° tilt (ArduCopter's ANGLE_MAX default is 30°, racers fly 45°+) and
  thrust-to-weight 2.5. Drag-limited speed ``m·g·tan 35° / k_t = 14.9 m/s``; reaches
  ≥ 5 m/s within about 2 s of a far position target (``tests/test_vehicle_profiles.py``).

A scenario selects one with ``profile = "fast"``; its ``[vehicle]`` and ``[control]``
sections then override single fields.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from plant_sim.params import ControlParams, QuadrotorParams

__all__ = ["PROFILES", "VehicleProfile", "profile", "terminal_speed_mps"]


@dataclass(frozen=True)
class VehicleProfile:
    """Airframe + controller parameters under one name."""

    name: str
    vehicle: QuadrotorParams = field(default_factory=QuadrotorParams)
    control: ControlParams = field(default_factory=ControlParams)


def _fast() -> VehicleProfile:
    mass_kg = QuadrotorParams().mass_kg
    return VehicleProfile(
        name="fast",
        vehicle=QuadrotorParams(
            drag_force_kgps=(0.3, 0.3, 0.6),
            rotor_thrust_max_n=2.5 * mass_kg * 9.81 / 4.0,
        ),
        control=ControlParams(max_tilt_deg=35.0),
    )


PROFILES: dict[str, VehicleProfile] = {
    "paper": VehicleProfile(name="paper"),
    "fast": _fast(),
}


def profile(name: str) -> VehicleProfile:
    """The profile called ``name``; ``ValueError`` naming the valid ones otherwise."""
    try:
        return PROFILES[name]
    except KeyError:
        raise ValueError(f"unknown vehicle profile {name!r}; valid: {sorted(PROFILES)}") from None


def terminal_speed_mps(p: VehicleProfile) -> float:
    """Level drag-limited speed at the tilt limit: ``m·g·tan(max_tilt) / k_t,x`` [m/s]."""
    v = p.vehicle
    return (
        v.mass_kg
        * v.gravity_mps2
        * math.tan(math.radians(p.control.max_tilt_deg))
        / (v.drag_force_kgps[0])
    )
