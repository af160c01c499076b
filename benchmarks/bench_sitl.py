"""ArduCopter SITL benchmarks (issue 12): the paper's scene on ArduPilot's own SITL.

Flies ``stereo-avoid sil --autopilot arducopter-sitl`` (WPNAV_SPEED 100) at SITL
``--speedup 1`` and then faster, and prints for each: wall time, verdict, clearance,
max speed and time to goal; the fastest speed-up whose verdict equals the real-time one
(pass/fail, and clearance on the same side of the tests' 0.5 m);
and plant-sim camera-only latency (pose sample received → frame published, wall ms)
p50/p99 from the real-time run. Prints figures; asserts nothing.

Run: ``OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_sitl.py [--speedups 2,3,5]``
(needs ``$ARDUCOPTER_SITL``: the real autopilot is opt-in).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from evaluation.sitl import (  # noqa: E402
    SITL_HOWTO,
    SitlOptions,
    find_arducopter_sitl,
    run_sitl_sil,
)


def _fly(binary: Path, speedup: float) -> dict:
    with tempfile.TemporaryDirectory(prefix="bench-sitl-") as tmp:
        result = run_sitl_sil(
            SitlOptions(
                binary=binary,
                out_dir=Path(tmp),
                speedup=speedup,
                params=(("WPNAV_SPEED", 100.0),),
            )
        )
    v, fig = result.sil.verdict, result.figures
    return {
        "speedup": speedup,
        "wall_s": v.wall_time_s,
        "passed": v.passed,
        "clearance_m": v.min_surface_distance_m,
        "max_speed_mps": fig["max_speed_mps"],
        "time_to_goal_s": fig["time_to_goal_s"],
        "latency_ms": fig["plant_latency_ms"],
    }


def _same_verdict(row: dict, reference: dict) -> bool:
    """The test suite's verdict: pass/fail, and a clearance on the same side of 0.5 m."""
    return row["passed"] == reference["passed"] and (row["clearance_m"] >= 0.5) == (
        reference["clearance_m"] >= 0.5
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--speedups", default="2,3,5,8", help="comma-separated, after 1")
    args = parser.parse_args()
    binary = find_arducopter_sitl()
    if binary is None:
        print(f"bench_sitl: {SITL_HOWTO}", file=sys.stderr)
        return 2
    rows = [_fly(binary, 1.0)]
    reference = rows[0]
    fastest, unchanged = 1.0, True
    for speedup in sorted(float(x) for x in args.speedups.split(",")):
        row = _fly(binary, speedup)
        rows.append(row)
        unchanged = unchanged and _same_verdict(row, reference)
        if unchanged:  # every speed-up up to this one gave the real-time verdict
            fastest = speedup
    print(
        f"{'speedup':>8} {'wall s':>8} {'verdict':>8} {'clear m':>8} {'max m/s':>8} {'goal s':>8}"
    )
    for r in rows:
        print(
            f"{r['speedup']:8g} {r['wall_s']:8.1f} {'PASS' if r['passed'] else 'FAIL':>8} "
            f"{r['clearance_m']:8.2f} {r['max_speed_mps'] or float('nan'):8.2f} "
            f"{r['time_to_goal_s'] or float('nan'):8.1f}"
        )
    print(f"wall time of the SITL paper scene at speedup 1: {reference['wall_s']:.1f} s")
    print(f"fastest speedup with the verdict of speedup 1: {fastest:g}")
    lat = reference["latency_ms"] or {}
    print(
        "plant-sim camera-only latency, pose sample -> frame published (speedup 1): "
        f"p50 {lat.get('pose_to_frame_p50')} ms, p99 {lat.get('pose_to_frame_p99')} ms "
        f"({lat.get('n')} frames)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
