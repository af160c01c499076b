"""An airframe flown through plant-sim's GUIDED mode logic in-process (no sockets): the
vehicle, the mode machine and its kinematics reader, for tests that fly targets the way
plant-sim's autopilot does (SIM_GUID_SHAPE 1)."""

from __future__ import annotations

from collections.abc import Callable

from plant_sim.autopilot.modes import FlightMode, FlightModeMachine, Kinematics, ModeTimings
from plant_sim.autopilot.params import ParamTable, timings_from_params
from plant_sim.profiles import profile
from plant_sim.vehicle import Quadrotor

__all__ = ["guided_airframe"]


def guided_airframe(
    profile_name: str, params: dict[str, float] | None = None
) -> tuple[Quadrotor, FlightModeMachine, Callable[[], Kinematics]]:
    """The ``profile_name`` airframe hovering at (0, 0, −7) NED, armed, in GUIDED with
    shaping on and its ANGLE_MAX, plus ``params``. Returns (vehicle, mode machine, a
    function reading the vehicle's kinematics for the machine)."""
    prof = profile(profile_name)
    quad = Quadrotor(prof.vehicle, prof.control, pos_ned_m=(0.0, 0.0, -7.0), ground_down_m=0.0)
    table = ParamTable({"ANGLE_MAX": prof.control.max_tilt_deg * 100.0, "SIM_GUID_SHAPE": 1.0})
    for name, value in (params or {}).items():
        assert table.set(name, value) is None, name

    def kin() -> Kinematics:
        s = quad.snapshot()
        return Kinematics(
            s.time_s,
            tuple(map(float, s.pos_ned_m)),
            tuple(map(float, s.vel_ned_mps)),
            s.yaw_rad,
            s.on_ground,
            s.tilt_saturated,
        )

    machine = FlightModeMachine(
        timings_from_params(ModeTimings(), table),
        home_ned_m=(0.0, 0.0, 0.0),
        ground_down_m=0.0,
        mode=FlightMode.GUIDED,
        armed=True,
        kin=kin(),
    )
    return quad, machine, kin
