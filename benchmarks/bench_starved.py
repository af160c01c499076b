"""Benchmark: a slow, busy companion (issue 32 item 6) — the paper's and the wall-behind
scenes with the companion held to 100 %, 50 % and 25 % of one core.

For each run: time to goal [s, autopilot time], top speed [m/s], least distance from the
vehicle's centre to a surface [m], and the companion's mode requests. Against plant-sim at
real time always; against ArduCopter SITL (at its real time) too when ``$ARDUCOPTER_SITL``
names a binary. Prints progress, then the table (docs/results.md) with the machine's load.

Run with ``OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_starved.py``
(``--fractions 1 0.5 0.25 --speedup 1``; about a minute per plant-sim run).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

from evaluation.scene_files import scenario_data
from evaluation.scenes import paper_scene
from evaluation.sil import SilOptions, _read_truth, run_sil
from evaluation.sitl import SitlOptions, find_arducopter_sitl, run_sitl_sil, speed_figures
from evaluation.sitl_scene import paper_sitl_scene, sitl_scene
from evaluation.starve import available

__all__ = ["main"]

WALL_BEHIND = {  # tests/test_sitl_arducopter.py's WALL_BEHIND_SCENARIO
    "goal_ned_m": [0.0, 0.0, -6.0],
    "start": {"pos_ned_m": [16.0, 1.0, -6.0], "yaw_deg": 0.0},
    "obstacles": [{"shape": "box", "center_ned_m": [6.0, 0.0, -4.0], "size_m": [0.4, 6.0, 8.0]}],
}


def _plant_sim_row(scene: str, fraction: float, speedup: float, out: Path) -> dict:
    data = (
        scenario_data(paper_scene())
        if scene == "paper"
        else {**WALL_BEHIND, "start": {**WALL_BEHIND["start"], "airborne": True}}
    )
    path = out / f"{scene}.json"
    path.write_text(json.dumps(data))
    result = run_sil(
        SilOptions(
            scenario_path=path,
            speedup=speedup,
            out_dir=out,
            max_time_s=150.0,
            companion_core_fraction=None if fraction >= 1.0 else fraction,
        )
    )
    v = result.verdict
    truth = _read_truth(result.truth_path)
    t0 = float(truth["time_s"][-1]) - v.sim_time_s
    speed = speed_figures(truth, t0, t0 + v.sim_time_s)["max_speed_mps"]
    return _row("plant-sim", scene, fraction, v, speed, result.companion_stats)


def _sitl_row(binary: Path, scene: str, fraction: float, out: Path) -> dict:
    sitl = paper_sitl_scene() if scene == "paper" else sitl_scene(WALL_BEHIND)
    result = run_sitl_sil(
        SitlOptions(
            binary=binary,
            out_dir=out,
            speedup=1.0,
            scene=sitl,
            scene_name=scene,
            companion_core_fraction=None if fraction >= 1.0 else fraction,
        )
    )
    v = result.sil.verdict
    speed = result.figures.get("max_speed_mps")
    return _row("ArduCopter SITL", scene, fraction, v, speed, result.sil.companion_stats)


def _row(autopilot, scene, fraction, v, top_speed, stats) -> dict:
    return {
        "autopilot": autopilot,
        "scene": scene,
        "core": fraction,
        "outcome": "goal" if v.reached_goal else ("collision" if v.collided else v.failure),
        "time_to_goal_s": round(v.sim_time_s, 1) if v.reached_goal else None,
        "top_speed_mps": top_speed,
        "least_surface_m": v.min_surface_distance_m,
        "mode_requests": (stats or {}).get("mode_requests"),
        "load": round(os.getloadavg()[0], 1),
    }


def _print_table(rows: list[dict]) -> None:
    print("| autopilot | scene | core | outcome | time to goal s | top speed m/s | "
          "least surface m | mode requests | load |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['autopilot']} | {r['scene']} | {r['core']:.0%} | {r['outcome']} | "
            f"{r['time_to_goal_s']} | {r['top_speed_mps']} | {r['least_surface_m']} | "
            f"{r['mode_requests']} | {r['load']} |"
        )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--fractions", type=float, nargs="+", default=[1.0, 0.5, 0.25])
    parser.add_argument("--scenes", nargs="+", default=["paper", "wall_behind"])
    parser.add_argument("--speedup", type=float, default=1.0, help="plant-sim's speed-up")
    parser.add_argument("--json", type=Path, help="also write the rows here")
    args = parser.parse_args(argv)
    mechanism, why = available()
    if mechanism is None:
        print(f"bench_starved: {why}", file=sys.stderr)
        return 2
    binary = find_arducopter_sitl()
    if binary is None:
        print("ArduCopter SITL: not run ($ARDUCOPTER_SITL is not set)")
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_starved_") as tmp:
        for scene in args.scenes:
            for fraction in args.fractions:
                for name in ("plant-sim", "sitl"):
                    if name == "sitl" and binary is None:
                        continue
                    out = Path(tmp) / f"{name}-{scene}-{fraction:g}"
                    out.mkdir()
                    t = time.monotonic()
                    if name == "plant-sim":
                        row = _plant_sim_row(scene, fraction, args.speedup, out)
                    else:
                        row = _sitl_row(binary, scene, fraction, out)
                    rows.append(row)
                    print(f"{name} {scene} {fraction:.0%} of a core: {row} "
                          f"({time.monotonic() - t:.0f} s wall)", flush=True)  # fmt: skip
    print(f"\nstarvation by {mechanism}; {os.cpu_count()} cpus")
    _print_table(rows)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
