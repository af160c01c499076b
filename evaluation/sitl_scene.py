"""A plant-sim scenario placed in ArduCopter SITL's world (pure: no files, no processes).

ArduCopter SITL starts disarmed on the ground at its home, which is the origin of its
LOCAL_NED; it flies its own physics. A scenario written for plant-sim (``[start]``,
``goal_ned_m``, ``[[obstacles]]``, ``[ground]``, ``[camera]``) is flown there by moving the
whole scene horizontally so that the start is home:

* every north/east coordinate (start, goal, obstacle centres) is shifted by
  ``-start.pos_ned_m[:2]``; down is kept (SITL's ground is at home, down 0);
* the companion takes off at home to the start's height (``-start.pos_ned_m[2]``), then
  flies to the shifted goal;
* SITL's start heading is the scenario's ``start.yaw_deg`` (``--home lat,lon,alt,yaw`` at
  SITL's own default site).

What SITL decides for itself is reported, not silently dropped: the vehicle profile and
parameters (``profile``, ``[vehicle]``, ``[control]``), the emulated autopilot's
``[failsafe]`` and ``[streams]``, ``[origin]``, and ``start.airborne``/``start.mode`` (SITL
always starts landed; the companion takes off in GUIDED).
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from plant_sim.scenario import Scenario, ScenarioError, scenario_from_dict

__all__ = [
    "SITL_HOME_LAT_LON_ALT",
    "SitlScene",
    "paper_sitl_scene",
    "sitl_scene",
]

#: ArduPilot SITL's default site (Canberra Model Aircraft Club): lat [deg], lon [deg],
#: altitude AMSL [m]. Used with ``--home`` when the scenario sets the start heading.
SITL_HOME_LAT_LON_ALT = (-35.363261, 149.165230, 584.0)
MIN_TAKEOFF_ALT_M = 1.0  # a start lower than this is too near the ground to take off to

_SITL_DECIDES = ("profile", "vehicle", "control", "failsafe", "streams", "origin")


@dataclass(frozen=True)
class SitlScene:
    """A scenario in SITL's LOCAL_NED (home = origin).

    Attributes
    ----------
    scenario : dict
        The shifted scenario for plant-sim (camera and ground truth), as parsed data.
    goal_ned_m : tuple of float
        The companion's goal [m, SITL LOCAL_NED].
    takeoff_alt_m : float
        Height above home the companion takes off to [m].
    heading_deg : float or None
        SITL's start heading [deg from north]; None: SITL's default.
    shift_ne_m : tuple of float
        What was added to every north, east coordinate of the scenario [m].
    not_applied : tuple of str
        Scenario settings SITL decides for itself (reported to the user).
    """

    scenario: dict
    goal_ned_m: tuple[float, float, float]
    takeoff_alt_m: float
    heading_deg: float | None
    shift_ne_m: tuple[float, float] = (0.0, 0.0)
    not_applied: tuple[str, ...] = ()

    def home_arg(self) -> str | None:
        """``--home`` for SITL (its default site, this heading), or None to keep its own."""
        if self.heading_deg is None:
            return None
        lat, lon, alt = SITL_HOME_LAT_LON_ALT
        return f"{lat},{lon},{alt:g},{self.heading_deg % 360.0:g}"


def paper_sitl_scene() -> SitlScene:
    """The paper's §6 flown northwards from home: takeoff to 7 m, the 1.5 m sphere 10 m
    north, the goal 20 m north; SITL's own start heading."""
    return SitlScene(
        scenario={
            "vehicle_id": "sim1",
            "goal_ned_m": [20.0, 0.0, -7.0],
            "start": {"pos_ned_m": [0.0, 0.0, -7.0], "yaw_deg": 0.0},
            "obstacles": [{"center_ned_m": [10.0, 0.0, -7.0], "radius_m": 1.5}],
            "ground": {"down_m": 0.0},
        },
        goal_ned_m=(20.0, 0.0, -7.0),
        takeoff_alt_m=7.0,
        heading_deg=None,
    )


def sitl_scene(data: Mapping[str, Any]) -> SitlScene:
    """Place the scenario ``data`` (a parsed plant-sim scenario file) in SITL's world.

    Raises
    ------
    ScenarioError
        If ``data`` is not a valid scenario, or cannot be flown on SITL: no goal, a ground
        other than at home's level, a start below ``MIN_TAKEOFF_ALT_M``.
    """
    scenario = scenario_from_dict(data)  # every key and value checked as for plant-sim
    _check_flyable(scenario)
    north, east, down = scenario.start.pos_ned_m
    shifted = copy.deepcopy(dict(data))
    shifted["start"] = {
        **dict(shifted.get("start", {})),
        "pos_ned_m": [0.0, 0.0, down],
        "yaw_deg": scenario.start.yaw_deg,
    }
    for key in ("airborne", "mode"):
        shifted["start"].pop(key, None)  # plant-sim here is the camera only
    assert scenario.goal_ned_m is not None
    goal = _shift(scenario.goal_ned_m, north, east)
    shifted["goal_ned_m"] = list(goal)
    if "obstacles" in data:
        shifted["obstacles"] = [
            {**dict(item), "center_ned_m": list(_shift(item["center_ned_m"], north, east))}
            for item in data["obstacles"]
        ]
    else:  # the paper's sphere, where plant-sim would put it
        shifted["obstacles"] = [
            {"center_ned_m": list(_shift(s.center_ned_m, north, east)), "radius_m": s.radius_m}
            for s in scenario.world.spheres
        ]
    scenario_from_dict(shifted)  # still valid after the move
    return SitlScene(
        scenario=shifted,
        goal_ned_m=goal,
        takeoff_alt_m=-down,
        heading_deg=scenario.start.yaw_deg,
        shift_ne_m=(_clean(-north), _clean(-east)),
        not_applied=_not_applied(data),
    )


def _check_flyable(scenario: Scenario) -> None:
    if scenario.goal_ned_m is None:
        raise ScenarioError("ArduCopter SITL needs a goal: goal_ned_m is false")
    ground = scenario.ground_down_m
    if ground is not None and ground != 0.0:
        raise ScenarioError(
            f"ArduCopter SITL's ground is level with its home (down 0 m); the scenario's "
            f"ground.down_m is {ground:g} m"
        )
    height = -scenario.start.pos_ned_m[2]
    if not height >= MIN_TAKEOFF_ALT_M:
        raise ScenarioError(
            f"ArduCopter SITL starts on the ground and the companion takes off to the start's "
            f"height: start.pos_ned_m down must be <= -{MIN_TAKEOFF_ALT_M:g} m, got "
            f"{scenario.start.pos_ned_m[2]:g}"
        )


def _shift(ned, north: float, east: float) -> tuple[float, float, float]:
    n, e, d = (float(x) for x in ned)
    return (_clean(n - north), _clean(e - east), d)


def _clean(x: float) -> float:
    """No ``-0.0`` in what is printed and written."""
    return x + 0.0


def _not_applied(data: Mapping[str, Any]) -> tuple[str, ...]:
    notes = [key for key in _SITL_DECIDES if key in data]
    start = data.get("start", {})
    if isinstance(start, Mapping):
        notes += [f"start.{key}" for key in ("airborne", "mode") if key in start]
    return tuple(notes)
