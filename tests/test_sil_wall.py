"""A textureless wall across the path with real processes (issue 14): plant-sim renders it,
the companion (safety envelope on) must stop the vehicle at least 0.5 m before it.

Both processes on 127.0.0.1 with free ports and explicit Zenoh endpoints; every wait is
bounded and the children's logs are printed on failure. The companion runs its default
configuration (known space's open sky reaches no farther than the last ground matched in
each column, so a wall taller than the view is not taken for sky).
"""

from __future__ import annotations

import socket

import numpy as np
import pytest

from evaluation.sil import ChildProcess, _read_truth, free_port

SPEEDUP = 4.0
STOP_CLEARANCE_M = 0.5
SIM_SECONDS = 20.0  # the companion may take seconds of wall time to steer under load

_SCENARIO = """\
profile = "{profile}"
goal_ned_m = [0.0, 0.0, -7.0]

[start]
pos_ned_m = [14.0, 0.0, -7.0]
yaw_deg = 180.0
airborne = true

[[obstacles]]
shape = "box"
center_ned_m = [10.0, 0.0, -7.0]
size_m = [0.2, 30.0, 14.0]
material = "textureless"
"""


@pytest.mark.slow
@pytest.mark.parametrize("profile", ["paper", "fast"])
def test_sil_stop_before_a_textureless_wall(tmp_path, profile):
    scenario = tmp_path / "wall.toml"
    scenario.write_text(_SCENARIO.format(profile=profile), encoding="utf-8")
    mav_port = free_port()
    companion_zenoh = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    plant_zenoh = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    children: list[ChildProcess] = []
    passed = False
    try:
        companion = ChildProcess(
            "companion",
            "companion",
            [
                "--mavlink",
                f"udpout:127.0.0.1:{mav_port}",
                "--zenoh-listen",
                companion_zenoh,
                "--goal",
                "0",
                "0",
                "-7",
            ],
        )
        children.append(companion)
        companion.wait_line(r"^COMPANION READY ", 60)
        plant = ChildProcess(
            "plant-sim",
            "plant_sim",
            [
                "--scenario",
                str(scenario),
                "--mavlink",
                f"udpin:127.0.0.1:{mav_port}",
                "--zenoh-listen",
                plant_zenoh,
                "--zenoh-connect",
                companion_zenoh,
                "--speedup",
                f"{SPEEDUP:g}",
                "--duration",
                f"{SIM_SECONDS:g}",
                "--log-dir",
                str(tmp_path / "run"),
            ],
        )
        children.append(plant)
        plant.wait_line(r"^PLANT_SIM READY ", 60)
        plant.proc.wait(timeout=240)  # runs out its simulation seconds, whatever the pace
        assert companion.events("steering"), "the companion never steered"
        truth = _read_truth(tmp_path / "run" / "truth.csv")
        surface = truth["surface_distance_m"]
        assert np.all(np.isfinite(surface)), "the truth log measures the distance to the wall"
        assert surface.min() >= STOP_CLEARANCE_M, surface.min()
        speed = np.sqrt(truth["vel_n_mps"] ** 2 + truth["vel_e_mps"] ** 2 + truth["vel_d_mps"] ** 2)
        assert speed[-50:].max() < 0.1, "stopped (the last second at 50 Hz)"
        print(f"{profile}: min surface distance {surface.min():.2f} m")
        passed = True
    finally:
        for c in reversed(children):
            c.stop()
        if not passed:
            print("\n".join(c.logs() for c in children))
        for c in children:
            c.close()
