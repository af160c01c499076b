"""Scenes for guidance that must find its way (issue 36): passages, goals near surfaces,
goals straight above or below.

Seeded families (:data:`PASSAGE_FAMILIES`, :func:`passage_scene`), each reproducible from
its seed. Walls are axis-aligned boxes (``plant_sim.world.Box``), so the straight path runs
along one of the four axis directions (the heading is drawn from them):

* ``gap`` — a wall across the path, from the ground to 14 m, 16–30 m wide (no way over or
  round within a short detour), with one opening 2.5–4 m wide whose centre lies within
  ±0.6 m of the straight path.
* ``corridor`` — two parallel walls along the path, 2.5–4 m apart, 8–14 m long, from the
  ground to 12 m; the straight path runs inside within ±0.3 m of its centre line.
* ``goal_surface`` — a goal 0.7–2 m from a wall's surface: beyond the goal (facing the
  vehicle), beside it (parallel to the path), or a thin wall 3–5 m wide between the start
  and a goal behind it.
* ``vertical`` — the goal 3–6 m straight above or below the start (within 0.05 m
  horizontally), with a wall beside the column 1.5–3 m away.

Every family but ``vertical`` keeps the start ≥ 5 m from any surface, and the goal's
nearest surface is where the family says; :func:`corridor_scene` and :func:`gap_scene` are
the fixed scenes the tests fly (the paper's start and goal, a 3 m passage on the straight
line).
"""

from __future__ import annotations

import math

import numpy as np

from evaluation.scenes import Scene
from plant_sim.world import Box, GroundPlane, World

__all__ = [
    "PASSAGE_FAMILIES",
    "corridor_scene",
    "gap_scene",
    "passage_scene",
    "passages_scene",
]

PASSAGE_FAMILIES: tuple[str, ...] = ("gap", "corridor", "goal_surface", "vertical")

WALL_THICKNESS_M = 0.3
PASSAGE_WIDTH_RANGE_M = (2.5, 4.0)
GOAL_SURFACE_RANGE_M = (0.7, 2.0)
VERTICAL_RANGE_M = (3.0, 6.0)
ALTITUDE_RANGE_M = (5.0, 8.0)
_HEADINGS = ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0))  # N, E, S, W


def _slab(along_m: float, lateral_m: float, span_along_m, span_lateral_m, heading, z) -> Box:
    """A box centred ``along_m`` ahead and ``lateral_m`` to the right of the origin on
    ``heading`` (a unit axis direction), spans given in the path's frame; ``z = (top_down_m,
    bottom_down_m)``."""
    h = np.array(heading)
    right = np.array([-h[1], h[0]])
    c = along_m * h + lateral_m * right
    size_n = abs(h[0]) * span_along_m + abs(right[0]) * span_lateral_m
    size_e = abs(h[1]) * span_along_m + abs(right[1]) * span_lateral_m
    top, bottom = z
    return Box((float(c[0]), float(c[1]), 0.5 * (top + bottom)), (size_n, size_e, bottom - top))


def _ned(origin, heading, along_m: float, lateral_m: float, down_m: float):
    h = np.array(heading)
    right = np.array([-h[1], h[0]])
    p = np.asarray(origin) + along_m * h + lateral_m * right
    return (float(p[0]), float(p[1]), float(down_m))


def _scene(name, seed, origin, heading, start, goal, boxes) -> Scene:
    boxes = tuple(
        Box(
            (b.center_ned_m[0] + origin[0], b.center_ned_m[1] + origin[1], b.center_ned_m[2]),
            b.size_m,
            texture_seed=i,
        )
        for i, b in enumerate(boxes)
    )
    return Scene(
        name=name,
        start_ned_m=start,
        goal_ned_m=goal,
        world=World(boxes=boxes, ground=GroundPlane()),
        seed=seed,
    )


def gap_scene(width_m: float = 3.0, wall_width_m: float = 30.0) -> Scene:
    """The paper's start and goal, a 12 m high wall across the path at north 10 m with an
    opening ``width_m`` wide centred on the straight line."""
    side = 0.5 * (wall_width_m - width_m)
    boxes = tuple(
        Box((10.0, s * (0.5 * width_m + 0.5 * side), -6.0), (WALL_THICKNESS_M, side, 12.0))
        for s in (-1.0, 1.0)
    )
    return Scene(
        name=f"gap-{width_m:g}m",
        start_ned_m=(20.0, 0.0, -7.0),
        goal_ned_m=(0.0, 0.0, -7.0),
        world=World(boxes=boxes, ground=GroundPlane()),
    )


def corridor_scene(width_m: float = 3.0, length_m: float = 12.0) -> Scene:
    """The paper's start and goal, two 8 m high walls ``width_m`` apart along the straight
    line, from north 16 m to ``16 − length_m``."""
    boxes = tuple(
        Box(
            (16.0 - 0.5 * length_m, s * 0.5 * (width_m + WALL_THICKNESS_M), -7.0),
            (length_m, WALL_THICKNESS_M, 8.0),
        )
        for s in (-1.0, 1.0)
    )
    return Scene(
        name=f"corridor-{width_m:g}m",
        start_ned_m=(20.0, 0.0, -7.0),
        goal_ned_m=(0.0, 0.0, -7.0),
        world=World(boxes=boxes, ground=GroundPlane()),
    )


def passage_scene(seed: int, family: str) -> Scene:
    """The random scene of ``seed`` in ``family`` (module docstring); reproducible."""
    if family not in PASSAGE_FAMILIES:
        raise ValueError(f"unknown passage family {family!r}; valid: {list(PASSAGE_FAMILIES)}")
    rng = np.random.default_rng([seed, 36, PASSAGE_FAMILIES.index(family)])
    origin = rng.uniform(-20.0, 20.0, 2)
    heading = _HEADINGS[int(rng.integers(4))]
    alt = rng.uniform(*ALTITUDE_RANGE_M)
    if family == "vertical":
        rise = rng.uniform(*VERTICAL_RANGE_M) * rng.choice([-1.0, 1.0])  # + up
        alt = rng.uniform(8.0, 10.0) if rise < 0 else rng.uniform(4.0, 6.0)
        beside = rng.uniform(1.5, 3.0) * rng.choice([-1.0, 1.0])
        wall_at = beside + math.copysign(0.5 * WALL_THICKNESS_M, beside)
        boxes = [_slab(0.0, wall_at, 6.0, WALL_THICKNESS_M, heading, (-16.0, 0.0))]
        off = rng.uniform(-0.05, 0.05, 2)
        start = _ned(origin, heading, 0.0, 0.0, -alt)
        goal = (start[0] + float(off[0]), start[1] + float(off[1]), -alt - rise)
    else:
        boxes, goal_at = _FAMILY_BOXES[family](rng, heading, alt)
        start = _ned(origin, heading, 0.0, 0.0, -alt)
        goal = _ned(origin, heading, goal_at, 0.0, -alt)
    return _scene(f"{family}-{seed}", seed, origin, heading, start, goal, boxes)


def passages_scene(seed: int) -> Scene:
    """The ``passages`` mix: the family of ``seed`` is ``PASSAGE_FAMILIES[seed % 4]``."""
    return passage_scene(seed, PASSAGE_FAMILIES[seed % len(PASSAGE_FAMILIES)])


def _gap_boxes(rng, heading, alt):
    t = WALL_THICKNESS_M
    width = rng.uniform(*PASSAGE_WIDTH_RANGE_M)
    centre = rng.uniform(-0.6, 0.6)
    wall_at = rng.uniform(6.0, 10.0)
    goal_at = wall_at + rng.uniform(5.0, 10.0)
    sides = rng.uniform(8.0, 15.0, 2)
    left = centre - 0.5 * width - 0.5 * sides[0]
    right = centre + 0.5 * width + 0.5 * sides[1]
    boxes = [
        _slab(wall_at, left, t, sides[0], heading, (-14.0, 0.0)),
        _slab(wall_at, right, t, sides[1], heading, (-14.0, 0.0)),
    ]
    return boxes, goal_at


def _corridor_boxes(rng, heading, alt):
    t = WALL_THICKNESS_M
    width = rng.uniform(*PASSAGE_WIDTH_RANGE_M)
    centre = rng.uniform(-0.3, 0.3)
    begin = rng.uniform(5.0, 8.0)
    length = rng.uniform(8.0, 14.0)
    goal_at = begin + length + rng.uniform(3.0, 6.0)
    mid = begin + 0.5 * length
    boxes = [
        _slab(mid, centre + s * 0.5 * (width + t), length, t, heading, (-12.0, 0.0))
        for s in (-1.0, 1.0)
    ]
    return boxes, goal_at


def _goal_surface_boxes(rng, heading, alt):
    t = WALL_THICKNESS_M
    gap = rng.uniform(*GOAL_SURFACE_RANGE_M)
    goal_at = rng.uniform(14.0, 20.0)
    kind = int(rng.integers(3))
    if kind == 0:  # a wall beyond the goal, facing the vehicle
        return [_slab(goal_at + gap + 0.5 * t, 0.0, t, 12.0, heading, (-alt - 4.0, 0.0))], goal_at
    if kind == 1:  # a wall beside the goal, along the path
        side = rng.choice([-1.0, 1.0])
        return [
            _slab(goal_at, side * (gap + 0.5 * t), 10.0, t, heading, (-alt - 4.0, 0.0))
        ], goal_at
    # a thin wall 3–5 m wide between the start and the goal, the goal behind it
    width = rng.uniform(3.0, 5.0)
    lateral = rng.uniform(-0.5, 0.5)
    z = (-alt - 2.0, -alt + 2.0)
    return [_slab(goal_at - gap - 0.5 * t, lateral, t, width, heading, z)], goal_at


_FAMILY_BOXES = {
    "gap": _gap_boxes,
    "corridor": _corridor_boxes,
    "goal_surface": _goal_surface_boxes,
}
