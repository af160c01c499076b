"""The paper's §6 scenario in the networked SIL with a depth camera (issue 35): plant-sim
publishes RealSense-like depth frames (``[camera] encoding = "depth16"``, noise on) over
Zenoh, the companion process takes them without a matcher. Both processes on 127.0.0.1 with
free ports and explicit endpoints (``plant_sim.lockstep.sil``: bounded waits, the children's
logs on failure). Judged like the stereo SIL (tests/test_companion_sil.py) against the
lockstep flight with the same camera.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from test_companion_sil import SPEEDUP, _assert_close_to_lockstep

from plant_sim.lockstep.harness import run_scene
from plant_sim.lockstep.montecarlo import run_config
from plant_sim.lockstep.scenes import paper_scene
from plant_sim.lockstep.sil import SilOptions, run_sil

_SCENARIO = """\
[camera]
encoding = "depth16"

[camera.depth]
subpixel_rms_px = 0.08
min_range_m = 1.0
"""

_COMPANION = """\
[perception.depth_camera]
min_range_m = 1.0
"""


@pytest.mark.slow
def test_sil_paper_scenario_with_depth_frames(tmp_path):
    scenario = tmp_path / "paper_depth16.toml"
    scenario.write_text(_SCENARIO, encoding="utf-8")
    config = tmp_path / "companion.toml"
    config.write_text(_COMPANION, encoding="utf-8")
    lockstep = run_scene(paper_scene(), run_config("depth")).verdict
    result = run_sil(
        SilOptions(
            scenario_path=scenario,
            speedup=SPEEDUP,
            out_dir=tmp_path / "run",
            companion_args=("--config", str(config)),
        )
    )
    v = result.verdict
    print(f"lockstep {lockstep}\nsil {v}")
    _assert_close_to_lockstep(v, lockstep, "sil depth16")
    stats = result.companion_stats
    assert stats["frames_processed"] > 300, stats
    log = Path(tmp_path / "run" / "companion.log").read_text()
    assert "bad camera frame" not in log and "unsupported pixel encoding" not in log
    assert "DEPTH16 320x240 (depth camera, no matcher)" in log
