"""Scenes for lockstep runs: the paper's §6 and seeded random scenes for Monte Carlo."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from plant_sim.world import GroundPlane, Sphere, World, paper_world

__all__ = ["Scene", "paper_scene", "random_scene"]


@dataclass(frozen=True)
class Scene:
    """Where a run starts, where it goes and what is in the way (LOCAL_NED, metres)."""

    name: str
    start_ned_m: tuple[float, float, float]
    goal_ned_m: tuple[float, float, float]
    world: World
    seed: int = 0

    @property
    def start_yaw_rad(self) -> float:
        """Heading from start to goal: the forward camera looks where the vehicle goes."""
        d = np.subtract(self.goal_ned_m, self.start_ned_m)
        return math.atan2(d[1], d[0])


def paper_scene() -> Scene:
    """§6: start (20, 0, −7), goal (0, 0, −7), a 1.5 m sphere at (10, 0, −7)."""
    return Scene(
        name="paper",
        start_ned_m=(20.0, 0.0, -7.0),
        goal_ned_m=(0.0, 0.0, -7.0),
        world=paper_world(),
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
