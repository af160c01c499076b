"""Scenes and scenario files are one description (issue 33 item 1: ``stereo-avoid fly``)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from evaluation.harness import RunConfig
from evaluation.scene_files import scenario_data, scene_and_config
from evaluation.scenes import FAMILIES, Scene, family_scene, paper_scene
from plant_sim.scenario import load_scenario, scenario_from_dict
from plant_sim.world import World

ROOT = Path(__file__).resolve().parents[1]


def _same_scene(a: Scene, b: Scene) -> None:
    assert a.start_ned_m == pytest.approx(b.start_ned_m, abs=1e-12)
    assert a.goal_ned_m == pytest.approx(b.goal_ned_m, abs=1e-12)
    assert math.isclose(a.start_yaw_rad, b.start_yaw_rad, abs_tol=1e-12)
    assert a.world == b.world


@pytest.mark.parametrize("family", FAMILIES)
def test_a_monte_carlo_scene_survives_the_round_trip_through_a_scenario(family):
    for seed in range(3):
        scene = family_scene(seed, family)
        if scene.via_ned_m:
            continue
        data = json.loads(json.dumps(scenario_data(scene)))  # what a .json file holds
        back, cfg = scene_and_config(scenario_from_dict(data), scene.name)
        _same_scene(back, scene)
        assert cfg == RunConfig()  # the paper airframe and camera


def test_the_compose_scenario_file_is_the_papers_flight():
    """``stereo-avoid fly --scenario docker/config/scenario.toml`` flies exactly what
    ``stereo-avoid paper`` flies: the same scene and configuration (the harness is
    deterministic, so the same verdict)."""
    scene, cfg = scene_and_config(load_scenario(ROOT / "docker/config/scenario.toml"), "x")
    _same_scene(scene, paper_scene())
    assert cfg == RunConfig()


def test_a_scenario_without_a_goal_or_on_the_ground_is_refused():
    with pytest.raises(ValueError, match="goal_ned_m"):
        scene_and_config(scenario_from_dict({"goal_ned_m": False}), "nogoal")
    with pytest.raises(ValueError, match="airborne"):
        scene_and_config(scenario_from_dict({"start": {"airborne": False}}), "ground")


def _fly(tmp_path: Path, scenario: dict | str) -> subprocess.CompletedProcess:
    path = tmp_path / "scene.json"
    path.write_text(scenario if isinstance(scenario, str) else json.dumps(scenario))
    out = tmp_path / "out"
    cmd = ["evaluation.cli", "fly", "--scenario", str(path), "--out", str(out), "--json"]
    return subprocess.run(
        [sys.executable, "-m", *cmd],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )


@pytest.mark.slow
def test_fly_a_scenario_of_your_own(tmp_path):
    """A short flight of the fast airframe past a pole: exit 0, the verdict and figures."""
    scenario = {
        "profile": "fast",
        "goal_ned_m": [0.0, 0.0, -5.0],
        "start": {"pos_ned_m": [8.0, 0.0, -5.0], "yaw_deg": 180.0},
        "obstacles": [
            {"shape": "cylinder", "center_ned_m": [4.0, 2.5, -5.0], "radius_m": 0.3, "height_m": 10}
        ],
    }
    done = _fly(tmp_path, scenario)
    assert done.returncode == 0, done.stdout + done.stderr
    verdict = json.loads(done.stdout)
    assert verdict["reached_goal"] and not verdict["collided"], verdict
    assert verdict["scene"] == "scene"
    assert (tmp_path / "out" / "fig6_trajectory.png").stat().st_size > 0
    assert json.loads((tmp_path / "out" / "verdict.json").read_text()) == verdict


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ('{"goal_ned_m": false}', "goal_ned_m"),
        ('{"obstacles": [{"radius_m": 1}]}', "center_ned_m"),
        ('{"wind": 3}', "wind"),
        ("{not json", "cannot parse"),
    ],
)
def test_fly_refuses_a_bad_scenario_with_exit_2(tmp_path, text, says):
    done = _fly(tmp_path, text)
    assert done.returncode == 2, done.stdout + done.stderr
    assert "stereo-avoid fly:" in done.stderr and says in done.stderr, done.stderr


def test_world_equality_is_what_the_round_trip_relies_on():
    assert paper_scene().world == paper_scene().world
    assert paper_scene().world != World()
