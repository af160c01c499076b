"""The paper's §6 scenario in the networked SIL with a depth camera (issue 35): plant-sim
publishes RealSense-like depth frames (``[camera] encoding = "depth16"``, noise on) over
Zenoh, the companion process takes them without a matcher. Both processes on 127.0.0.1 with
free ports and explicit endpoints (``evaluation.sil``: bounded waits, the children's
logs on failure). Judged against the lockstep flight with the same camera like the stereo
SIL (tests/test_companion_sil.py), with a wider bound on the flight time (see the test).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from evaluation.harness import run_scene
from evaluation.montecarlo import run_config
from evaluation.scenes import paper_scene
from evaluation.sil import SilOptions, run_sil

# 2x, not the stereo SIL's 4x: the harness's wall-clock deadline (90 s / speedup + 10 s)
# assumes plant-sim keeps the speed-up, which it did not at 4x on the shared 2-core
# machine at load 14 (sim 21.8 s of the ~30 s flight in 32 s of wall time).
SPEEDUP = 2.0

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
    assert v.reached_goal and not v.collided and v.failure is None, v
    assert v.min_surface_distance_m >= 0.5, v
    assert abs(v.min_surface_distance_m - lockstep.min_surface_distance_m) <= 0.45, (v, lockstep)
    assert v.max_pitch_cmd_deg <= 15.0 + 1e-6 and v.max_roll_cmd_deg <= 15.0 + 1e-6
    # Not faster than lockstep (less a frame's worth of path), and slower by a bound: the
    # envelope slows a companion whose frames age (measured at load 14: data age p99
    # 166 ms, stale-frame holds, 37.8 s against lockstep's 27.4 s; the stereo SIL's 4 s
    # tolerance was measured on a quiet machine).
    assert lockstep.sim_time_s - 4.0 <= v.sim_time_s <= lockstep.sim_time_s + 15.0, (v, lockstep)
    stats = result.companion_stats
    assert stats["frames_processed"] > 300, stats
    log = Path(tmp_path / "run" / "companion.log").read_text()
    assert "bad camera frame" not in log and "unsupported pixel encoding" not in log
    assert "DEPTH16 320x240 (depth camera, no matcher)" in log
