"""Scenes for lockstep runs: the paper's §6 and seeded random scenes for Monte Carlo.

Random scene families (:data:`FAMILIES`, :func:`family_scene`), each reproducible from
its seed:

* ``path`` — :func:`random_scene`: 1–3 spheres on or near a level straight path.
* ``climb`` — the same around a path that climbs or descends 2–5 m (at most 11°), so the
  vehicle passes above or below obstacles.
* ``goal_near`` — one extra sphere whose surface lies 0–1.5 m from the goal (beyond or
  beside it): the goal is reached or the vehicle stops, reported, outside the sphere.
* ``facing_away`` — the vehicle starts facing away from the goal with an extra sphere
  1.5–2.5 m behind it (between it and the goal): it must turn and look before moving.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from plant_sim.world import Box, GroundPlane, Material, Sphere, World, paper_world

__all__ = [
    "FAMILIES",
    "Scene",
    "family_scene",
    "mixed_scene",
    "paper_scene",
    "random_scene",
    "wall_scene",
]


@dataclass(frozen=True)
class Scene:
    """Where a run starts, where it goes and what is in the way (LOCAL_NED, metres)."""

    name: str
    start_ned_m: tuple[float, float, float]
    goal_ned_m: tuple[float, float, float]
    world: World
    seed: int = 0
    yaw_rad: float | None = None  # start heading [rad]; None: facing the first waypoint
    via_ned_m: tuple[tuple[float, float, float], ...] = ()  # waypoints before the goal

    @property
    def waypoints_ned_m(self) -> tuple[tuple[float, float, float], ...]:
        """The mission: the ``via_ned_m`` waypoints in order, then the goal."""
        return (*self.via_ned_m, self.goal_ned_m)

    @property
    def start_yaw_rad(self) -> float:
        """Start heading: ``yaw_rad``, or toward the first waypoint (the camera looks ahead)."""
        if self.yaw_rad is not None:
            return self.yaw_rad
        d = np.subtract(self.waypoints_ned_m[0], self.start_ned_m)
        return math.atan2(d[1], d[0])


def paper_scene() -> Scene:
    """§6: start (20, 0, −7), goal (0, 0, −7), a 1.5 m sphere at (10, 0, −7)."""
    return Scene(
        name="paper",
        start_ned_m=(20.0, 0.0, -7.0),
        goal_ned_m=(0.0, 0.0, -7.0),
        world=paper_world(),
    )


def wall_scene(start_north_m: float = 14.0) -> Scene:
    """The paper's path blocked by a textureless wall (issue 14): 30 m wide, from the ground
    to 14 m up, its face at north 10.1 m, wider and taller than the view from anywhere on
    the path. Nothing on it can be matched; the only safe outcome is a stop before it."""
    wall = Box((10.0, 0.0, -7.0), (0.2, 30.0, 14.0), material=Material.TEXTURELESS)
    return Scene(
        name="wall",
        start_ned_m=(start_north_m, 0.0, -7.0),
        goal_ned_m=(0.0, 0.0, -7.0),
        world=World(boxes=(wall,), ground=GroundPlane(0.0)),
    )


# Random-scene envelope. Spheres sit on or near the straight start→goal line; their
# surfaces keep MIN_GAP_M apart (so a vehicle of radius 0.35 m plus margin fits between
# them) and keep clear of the start (the camera must see them coming) and the goal.
RADIUS_RANGE_M = (0.5, 2.0)
PATH_LENGTH_RANGE_M = (15.0, 30.0)
ALTITUDE_RANGE_M = (5.0, 10.0)
MIN_GAP_M = 2.5
START_CLEARANCE_M = 6.0
GOAL_CLEARANCE_M = 3.0


def random_scene(seed: int, *, max_tries: int = 1000) -> Scene:
    """A reproducible random scene: 1–3 spheres of radius 0.5–2 m near the straight path.

    The same ``seed`` always gives the same scene, so a failing Monte Carlo sample can be
    replayed by its seed alone.
    """
    rng = np.random.default_rng(seed)
    altitude = rng.uniform(*ALTITUDE_RANGE_M)
    start = np.array([*rng.uniform(-20.0, 20.0, 2), -altitude])
    heading = rng.uniform(-math.pi, math.pi)
    length = rng.uniform(*PATH_LENGTH_RANGE_M)
    direction = np.array([math.cos(heading), math.sin(heading), 0.0])
    goal = start + length * direction
    lateral = np.array([-direction[1], direction[0], 0.0])
    n_spheres = int(rng.integers(1, 4))
    spheres: list[Sphere] = []
    for _ in range(max_tries):
        if len(spheres) == n_spheres:
            break
        radius = rng.uniform(*RADIUS_RANGE_M)
        along = rng.uniform(0.3, 0.8) * length
        offset = rng.normal(0.0, 0.4 * radius)  # on or near the path
        vertical = rng.normal(0.0, 0.2 * radius)
        centre = start + along * direction + offset * lateral + np.array([0.0, 0.0, vertical])
        if centre[2] + radius > -1.0:  # keep it off the ground
            continue
        if np.linalg.norm(centre - start) - radius < START_CLEARANCE_M:
            continue
        if np.linalg.norm(centre - goal) - radius < GOAL_CLEARANCE_M:
            continue
        if any(
            np.linalg.norm(centre - np.array(s.center_ned_m)) - radius - s.radius_m < MIN_GAP_M
            for s in spheres
        ):
            continue
        spheres.append(
            Sphere(center_ned_m=tuple(centre), radius_m=float(radius), texture_seed=len(spheres))
        )
    if not spheres:
        raise RuntimeError(f"seed {seed}: no obstacle placement found in {max_tries} tries")
    return Scene(
        name=f"random-{seed}",
        start_ned_m=tuple(float(v) for v in start),
        goal_ned_m=tuple(float(v) for v in goal),
        world=World(spheres=tuple(spheres), ground=GroundPlane()),
        seed=seed,
    )


FAMILIES: tuple[str, ...] = ("path", "climb", "goal_near", "facing_away")


def _clear_of(centre: np.ndarray, radius: float, spheres: list[Sphere]) -> bool:
    return all(
        np.linalg.norm(centre - np.array(s.center_ned_m)) - radius - s.radius_m >= MIN_GAP_M
        for s in spheres
    )


def _climb_scene(seed: int, rng: np.random.Generator, max_tries: int = 1000) -> Scene:
    altitude = rng.uniform(*ALTITUDE_RANGE_M)
    start = np.array([*rng.uniform(-20.0, 20.0, 2), -altitude])
    heading = rng.uniform(-math.pi, math.pi)
    length = rng.uniform(*PATH_LENGTH_RANGE_M)
    climb = rng.uniform(2.0, min(5.0, 0.2 * length)) * rng.choice([-1.0, 1.0])
    climb = max(min(climb, 14.0 - altitude), 3.0 - altitude)  # stay 3–14 m up
    goal = start + np.array([length * math.cos(heading), length * math.sin(heading), -climb])
    direction = (goal - start) / np.linalg.norm(goal - start)
    lateral = np.array([-math.sin(heading), math.cos(heading), 0.0])
    spheres: list[Sphere] = []
    n_spheres = int(rng.integers(1, 4))
    for _ in range(max_tries):
        if len(spheres) == n_spheres:
            break
        radius = rng.uniform(*RADIUS_RANGE_M)
        along = rng.uniform(0.3, 0.8) * np.linalg.norm(goal - start)
        # beside, above or below the sloping path
        offset = rng.normal(0.0, 0.4 * radius) * lateral + np.array(
            [0.0, 0.0, rng.normal(0.0, 0.6 * radius)]
        )
        centre = start + along * direction + offset
        if centre[2] + radius > -1.0:
            continue
        if np.linalg.norm(centre - start) - radius < START_CLEARANCE_M:
            continue
        if np.linalg.norm(centre - goal) - radius < GOAL_CLEARANCE_M:
            continue
        if not _clear_of(centre, radius, spheres):
            continue
        spheres.append(Sphere(tuple(centre), float(radius), texture_seed=len(spheres)))
    if not spheres:
        raise RuntimeError(f"seed {seed}: no obstacle placement found in {max_tries} tries")
    return Scene(
        name=f"climb-{seed}",
        start_ned_m=tuple(float(v) for v in start),
        goal_ned_m=tuple(float(v) for v in goal),
        world=World(spheres=tuple(spheres), ground=GroundPlane()),
        seed=seed,
    )


def _add_sphere(base: Scene, rng, place, name: str, max_tries: int = 1000, **kw) -> Scene:
    """``base`` plus one sphere from ``place(rng) -> (centre, radius)`` clear of the others."""
    spheres = list(base.world.spheres)
    for _ in range(max_tries):
        centre, radius = place(rng)
        if centre[2] + radius > -1.0 or not _clear_of(centre, radius, spheres):
            continue
        spheres.append(Sphere(tuple(centre), float(radius), texture_seed=len(spheres)))
        return Scene(
            name=name,
            start_ned_m=base.start_ned_m,
            goal_ned_m=base.goal_ned_m,
            world=World(spheres=tuple(spheres), ground=base.world.ground),
            seed=base.seed,
            **kw,
        )
    raise RuntimeError(f"{name}: no placement for the extra sphere in {max_tries} tries")


def family_scene(seed: int, family: str) -> Scene:
    """The random scene of ``seed`` in ``family`` (module docstring); reproducible."""
    if family not in FAMILIES:
        raise ValueError(f"unknown scene family {family!r}; valid: {list(FAMILIES)}")
    if family == "path":
        return random_scene(seed)
    rng = np.random.default_rng([seed, FAMILIES.index(family)])
    if family == "climb":
        return _climb_scene(seed, rng)
    base = random_scene(seed)
    start, goal = np.array(base.start_ned_m), np.array(base.goal_ned_m)
    direction = (goal - start) / np.linalg.norm(goal - start)
    if family == "goal_near":

        def near_goal(r):
            radius = r.uniform(*RADIUS_RANGE_M)
            # beyond the goal or beside it, mostly level
            d = direction + r.normal(0.0, 0.7, 3) * np.array([1.0, 1.0, 0.3])
            d /= np.linalg.norm(d)
            return goal + d * (radius + r.uniform(0.0, 1.5)), radius

        return _add_sphere(base, rng, near_goal, f"goal_near-{seed}")

    def behind(r):
        radius = r.uniform(0.5, 1.5)
        lateral = np.array([-direction[1], direction[0], 0.0]) * r.normal(0.0, 0.3)
        return start + direction * (r.uniform(1.5, 2.5) + radius) + lateral, radius

    heading = math.atan2(direction[1], direction[0])
    yaw = math.atan2(math.sin(heading + math.pi), math.cos(heading + math.pi))
    return _add_sphere(base, rng, behind, f"facing_away-{seed}", yaw_rad=yaw)


def mixed_scene(seed: int) -> Scene:
    """Monte Carlo's default: the family of ``seed`` is ``FAMILIES[seed % 4]``."""
    return family_scene(seed, FAMILIES[seed % len(FAMILIES)])
