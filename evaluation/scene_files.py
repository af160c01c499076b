"""Lockstep scenes and plant-sim scenario files are one description of a flight.

* :func:`scenario_data` writes a lockstep :class:`~evaluation.scenes.Scene` as plant-sim
  scenario data (the dict a ``.json``/``.toml`` scenario file holds), so any scene — the
  paper's, a Monte Carlo seed — can be flown by the real processes (SIL, starved
  companion tests, ArduCopter SITL through :mod:`evaluation.sitl_scene`);
* :func:`scene_and_config` reads a scenario file's :class:`~plant_sim.scenario.Scenario`
  as a scene and the lockstep configuration it implies (airframe, camera), for
  ``stereo-avoid fly --scenario FILE``.

Pure: dicts and dataclasses in and out; reading the file is the caller's
(:func:`plant_sim.scenario.load_scenario`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from evaluation.harness import RunConfig
from evaluation.scenes import Scene
from plant_sim.scenario import Scenario
from plant_sim.world import World

__all__ = ["scenario_data", "scene_and_config"]


def _obstacle_rows(world: World) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    for s in world.spheres:
        rows.append(
            {"shape": "sphere", "center_ned_m": list(s.center_ned_m), "radius_m": s.radius_m}
        )
    for b in world.boxes:
        rows.append(
            {"shape": "box", "center_ned_m": list(b.center_ned_m), "size_m": list(b.size_m)}
        )
    for c in world.cylinders:
        rows.append(
            {
                "shape": "cylinder",
                "center_ned_m": list(c.center_ned_m),
                "radius_m": c.radius_m,
                "height_m": c.height_m,
            }
        )
    shapes = (*world.spheres, *world.boxes, *world.cylinders)
    for row, shape in zip(rows, shapes, strict=True):
        row["texture_seed"] = shape.texture_seed
        row["material"] = shape.material.value
    return rows


def scenario_data(scene: Scene, *, profile: str = "paper") -> dict[str, Any]:
    """``scene`` as plant-sim scenario data: airborne at its start, facing its start
    heading, its world and goal, the ``profile`` airframe.

    Raises
    ------
    ValueError
        For a scene with waypoints before the goal (plant-sim's scenario has one goal;
        give the companion the waypoints instead).
    """
    if scene.via_ned_m:
        raise ValueError(f"scene {scene.name!r} has waypoints: a scenario file has one goal")
    ground = scene.world.ground
    return {
        "profile": profile,
        "goal_ned_m": [float(v) for v in scene.goal_ned_m],
        "start": {
            "pos_ned_m": [float(v) for v in scene.start_ned_m],
            "yaw_deg": math.degrees(scene.start_yaw_rad),
            "airborne": True,
        },
        "obstacles": _obstacle_rows(scene.world),
        "ground": False
        if ground is None
        else {"down_m": ground.down_m, "texture_seed": ground.texture_seed},
    }


def scene_and_config(
    scenario: Scenario, name: str, base: RunConfig | None = None
) -> tuple[Scene, RunConfig]:
    """A scenario file's flight for the lockstep harness: the scene (its start, heading,
    goal and world) and ``base`` with the scenario's airframe and camera.

    Raises
    ------
    ValueError
        For a scenario without a goal (``goal_ned_m = false``: nothing to fly to) or one
        that starts on the ground (the lockstep harness starts airborne).
    """
    if scenario.goal_ned_m is None:
        raise ValueError(f"{name}: the scenario has no goal_ned_m; lockstep needs one")
    if not scenario.start.airborne:
        raise ValueError(f"{name}: start.airborne = false; lockstep flights start airborne")
    scene = Scene(
        name=name,
        start_ned_m=tuple(float(v) for v in scenario.start.pos_ned_m),
        goal_ned_m=tuple(float(v) for v in scenario.goal_ned_m),
        world=scenario.world,
        yaw_rad=math.radians(scenario.start.yaw_deg),
    )
    cfg = base or RunConfig()
    cfg = dataclasses.replace(
        cfg,
        vehicle=scenario.vehicle,
        control=scenario.control,
        camera=scenario.camera.model,
        render=scenario.camera.render,
        camera_rate_hz=scenario.camera.rate_hz,
    )
    return scene, cfg
