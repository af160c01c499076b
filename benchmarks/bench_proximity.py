"""Benchmark: OBSTACLE_DISTANCE's send intervals on a busy machine (issue 34).

plant-sim (ArduCopter flavour, the paper's sphere 10 m ahead, 30 Hz stereo camera) and
the companion (reporting only) run at real time beside ``--busy`` spinning processes
(``python -c "while True: pass"`` at nice 0) for ``--seconds``; a pymavlink client on
plant-sim's port times each OBSTACLE_DISTANCE that plant-sim forwards from the companion
(as a MAVLink router forwards to a ground station). Once per mode: the stream in its own
process (``[proximity] own_process = true``, the default: it sends through the companion's
socket), the watchdog thread (``own_process = false``) and the main loop alone
(``thread = false``). Prints, per
mode, the receipt intervals' p50, p99 and maximum [ms], the count over 0.5 s (the
autopilots' proximity timeout) and the frames the companion processed, with the
machine's load (``os.getloadavg``).

Run with ``OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_proximity.py``
(``--seconds 30 --busy 3 --modes process thread main``; about 80 s per mode). The
companion's own figures (``sender``: its longest gap between sends, before plant-sim's
forwarding) are printed beside the ground station's.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from pymavlink import mavutil

from evaluation.sil import ChildProcess, free_port

__all__ = ["main"]

_SCENARIO = """\
profile = "fast"
goal_ned_m = [0.0, 0.0, -7.0]

[start]
pos_ned_m = [20.0, 0.0, -7.0]
yaw_deg = 180.0
airborne = true
mode = "LOITER"

[[obstacles]]
center_ned_m = [10.0, 0.0, -7.0]
radius_m = 1.5
"""
_COMPANION = 196  # MAV_COMP_ID_OBSTACLE_AVOIDANCE
_MODES = {  # the [proximity] settings of each mode
    "process": "thread = true\nown_process = true\n",
    "thread": "thread = true\nown_process = false\n",
    "main": "thread = false\n",
}


def _intervals(m, seconds: float) -> np.ndarray:
    """Receipt intervals [s] of the companion's OBSTACLE_DISTANCE over ``seconds``."""
    times = []
    deadline = time.monotonic() + seconds
    while (left := deadline - time.monotonic()) > 0:
        msg = m.recv_match(type="OBSTACLE_DISTANCE", blocking=True, timeout=min(left, 0.1))
        if msg is not None and msg.get_srcComponent() == _COMPANION:
            times.append(time.monotonic())
    return np.diff(np.array(times))


def _run(mode: str, seconds: float, busy: int, out: Path) -> dict:
    scenario = out / "scene.toml"
    scenario.write_text(_SCENARIO, encoding="utf-8")
    config = out / f"companion-{mode}.toml"
    config.write_text(f"[proximity]\n{_MODES[mode]}", "utf-8")
    mav_port = free_port()
    plant_zenoh = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    companion_zenoh = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    spinners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(busy)]
    children: list[ChildProcess] = []
    try:
        companion = ChildProcess(
            "companion",
            "companion",
            ["--config", str(config), "--mavlink", f"udpout:127.0.0.1:{mav_port}",
             "--zenoh-listen", companion_zenoh, "--no-request-mode"],
        )  # fmt: skip
        children.append(companion)
        companion.wait_line(r"^COMPANION READY ", 120)
        plant = ChildProcess(
            "plant-sim",
            "plant_sim",
            ["--scenario", str(scenario), "--mavlink", f"udpin:127.0.0.1:{mav_port}",
             "--zenoh-listen", plant_zenoh, "--zenoh-connect", companion_zenoh,
             "--duration", f"{seconds + 30.0:g}"],
        )  # fmt: skip
        children.append(plant)
        plant.wait_line(r"^PLANT_SIM READY ", 120)
        m = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{mav_port}", source_system=255, dialect="ardupilotmega"
        )
        try:
            m.mav.heartbeat_send(6, 8, 0, 0, 0)  # say hello: plant-sim answers whoever writes
            _intervals(m, 5.0)  # the companion's kernels compile, its map fills
            load_before = os.getloadavg()[0]
            gaps = _intervals(m, seconds)
            load_after = os.getloadavg()[0]
        finally:
            m.close()
        companion.stop()
        stats = {}
        for line in companion.stdout_lines:
            if line.startswith("COMPANION STATS "):
                stats = json.loads(line[len("COMPANION STATS ") :])
    finally:
        for child in reversed(children):
            child.stop()
            child.close()
        for p in spinners:
            p.kill()
            p.wait()
    if gaps.size == 0:
        raise RuntimeError("no OBSTACLE_DISTANCE arrived")
    p50, p99 = np.percentile(gaps, [50.0, 99.0]) * 1e3
    return {
        "mode": mode,
        "load": f"{load_before:.1f}-{load_after:.1f}",
        "messages": int(gaps.size) + 1,
        "p50_ms": round(float(p50), 1),
        "p99_ms": round(float(p99), 1),
        "max_ms": round(float(gaps.max()) * 1e3, 1),
        "over_500ms": int(np.count_nonzero(gaps > 0.5)),
        "frames_processed": stats.get("frames_processed"),
        "sender": stats.get("obstacle_distance_thread"),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=30.0, help="measured time per mode [s]")
    ap.add_argument("--busy", type=int, default=3, help="spinning processes beside the run")
    ap.add_argument("--modes", nargs="+", choices=tuple(_MODES), default=list(_MODES))
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for mode in args.modes:
            print(f"OBSTACLE_DISTANCE from the {mode}, {args.busy} busy processes ...", flush=True)
            rows.append(_run(mode, args.seconds, args.busy, Path(tmp)))
            print(json.dumps(rows[-1]), flush=True)
    print(f"\n{os.cpu_count()} cores; intervals between OBSTACLE_DISTANCE at the ground station")
    print("| sender | load | messages | p50 [ms] | p99 [ms] | max [ms] | > 0.5 s | frames |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['mode']} | {r['load']} | {r['messages']} | {r['p50_ms']} | {r['p99_ms']} "
            f"| {r['max_ms']} | {r['over_500ms']} | {r['frames_processed']} |"
        )
    return 0


if __name__ == "__main__":
    with contextlib.suppress(KeyboardInterrupt):
        sys.exit(main())
