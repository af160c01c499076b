"""Vehicle profiles: named sets of airframe and controller parameters for plant-sim.

* ``paper`` (default) — Table 2 exactly, ±15° tilt (§6.1): drag-limited to
  ``m·g·tan 15° / k_t = 0.85 m/s``.
* ``fast`` — a racing-size camera quad, so the safety envelope is exercised at the speeds a
  real autopilot flies a far position target (ArduCopter's WPNAV_SPEED defaults to
  10 m/s): translational drag ``k_t = (0.3, 0.3, 0.6) kg/s`` (a streamlined 0.65 kg
  airframe), ±35° tilt (ArduCopter's ANGLE_MAX default is 30°, racers fly 45°+) and
  thrust-to-weight 2.5. Drag-limited speed ``m·g·tan 35° / k_t = 14.9 m/s``; reaches
  ≥ 5 m/s within about 1.2 s of a far position target (``tests/test_vehicle_profiles.py``).
  Its tilt follows a command as fast as ArduCopter's does (:data:`FAST_ATTITUDE_Q`), not
  at the paper's pace.

A scenario selects one with ``profile = "fast"``; its ``[vehicle]`` and ``[control]``
sections then override single fields.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from plant_sim.params import ControlParams, QuadrotorParams

__all__ = [
    "FAST_ATTITUDE_Q",
    "FAST_TILT_LAG_S",
    "PROFILES",
    "VehicleProfile",
    "profile",
    "terminal_speed_mps",
]

#: The ``fast`` airframe's tilt lag behind a ramped command [s]: ArduCopter's
#: ``ATC_INPUT_TC`` default (``AC_ATTITUDE_CONTROL_INPUT_TC_DEFAULT`` 0.15 s,
#: ``libraries/AC_AttitudeControl/AC_AttitudeControl.cpp``). ArduCopter shapes each
#: attitude command with that time constant and feeds the shaped target's rate forward
#: (``ATC_RATE_FF_ENAB`` 1) to a rate loop tens of rad/s fast, behind ``ATC_ANG_PIT_P``
#: 4.5 /s that only corrects what is left: the vehicle's tilt trails its command by about
#: the input time constant. The paper's attitude LQ (Eq. 29-31: poles −1.3 and −7.6 rad/s)
#: trails a ramp by ``k_d/k_p = 0.89 s``, six times that: a fast airframe flown by it
#: carried its own avoidance's stop 0.3-0.45 m past the margin (issue 34).
FAST_TILT_LAG_S = 0.154
#: Roll and pitch weights ``(q_angle, q_rate)`` of the ``fast`` airframe's attitude LQ
#: (Eq. 29's form, ``R`` = 0.1 as Eq. 30). A double integrator's LQ gains are
#: ``k_p = √(q_angle/r)``, ``k_d = √(q_rate/r + 2 k_p)``: these give ``k_p = 169 /s²``,
#: ``k_d = 26 /s`` (poles −13 ± 0 rad/s, critically damped) and a ramp lag
#: ``k_d/k_p`` = :data:`FAST_TILT_LAG_S`. Yaw keeps the paper's weights.
FAST_ATTITUDE_Q = (2856.1, 33.8)


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
        control=ControlParams(
            max_tilt_deg=35.0,
            q_attitude=(*FAST_ATTITUDE_Q, *FAST_ATTITUDE_Q, *ControlParams().q_attitude[4:]),
        ),
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
