"""plant-sim benchmarks (issue 5): maximum real-time factor, 50 Hz telemetry loss.

Runs real ``python -m plant_sim`` processes on 127.0.0.1. Prints figures; asserts nothing.
Run: ``OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_plant_sim.py``.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

from pymavlink import mavutil

REPO = Path(__file__).resolve().parents[1]


def _free_port(kind=socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _run(args: list[str], timeout_s: float = 300.0) -> dict:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    out = subprocess.run(
        [sys.executable, "-m", "plant_sim", "--no-logs", *args],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout_s,
        check=True,
    ).stdout
    for line in out.splitlines():
        if line.startswith("PLANT_SIM STATS "):
            return json.loads(line[len("PLANT_SIM STATS ") :])
    raise RuntimeError(f"no stats line:\n{out}")


def max_rtf(camera: bool, sim_s: float) -> float:
    args = ["--mavlink", "udpin:127.0.0.1:0", "--speedup", "max", "--duration", str(sim_s)]
    if camera:
        args += [
            "--zenoh-listen",
            f"tcp/127.0.0.1:{_free_port(socket.SOCK_STREAM)}",
            "--camera-rate-hz",
            "30",
        ]
    else:
        args.append("--no-camera")
    stats = _run(args)
    return stats["real_time_factor"]  # main loop only (start-up and JIT excluded)


def telemetry_loss(rate_hz: float = 50.0, seconds: float = 20.0) -> dict[str, float]:
    port = _free_port()
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "plant_sim",
            "--no-logs",
            "--mavlink",
            f"udpin:127.0.0.1:{port}",
            "--speedup",
            "1",
            "--zenoh-listen",
            f"tcp/127.0.0.1:{_free_port(socket.SOCK_STREAM)}",
        ],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        assert "PLANT_SIM READY" in proc.stdout.readline()
        m = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255)
        m.mav.heartbeat_send(6, 8, 0, 0, 0)
        m.recv_match(type="HEARTBEAT", blocking=True, timeout=10)
        names = (
            "LOCAL_POSITION_NED",
            "ATTITUDE",
            "GLOBAL_POSITION_INT",
            "POSITION_TARGET_LOCAL_NED",
        )
        for name in names:
            msg_id = getattr(mavutil.mavlink, f"MAVLINK_MSG_ID_{name}")
            m.mav.command_long_send(1, 1, 511, 0, msg_id, 1e6 / rate_hz, 0, 0, 0, 0, 0)
        t_end = time.monotonic() + 1.0
        while time.monotonic() < t_end:
            m.recv_match(blocking=True, timeout=0.1)
        stamps: dict[str, list[int]] = {n: [] for n in names}
        t_end = time.monotonic() + seconds
        while time.monotonic() < t_end:
            msg = m.recv_match(type=list(names), blocking=True, timeout=0.5)
            if msg is not None:
                stamps[msg.get_type()].append(msg.time_boot_ms)
        m.close()
        loss = {}
        for name, t in stamps.items():
            expected = (t[-1] - t[0]) / (1000.0 / rate_hz) + 1
            loss[name] = 100.0 * (1.0 - len(t) / expected)
        return loss
    finally:
        proc.terminate()
        proc.wait(timeout=20)


def main() -> None:
    print(f"max real-time factor, camera off      : {max_rtf(False, 600.0):7.1f}x")
    print(f"max real-time factor, 320x240 @ 30 Hz : {max_rtf(True, 60.0):7.1f}x")
    for name, pct in telemetry_loss().items():
        print(f"50 Hz {name:26s} (camera on, 1x): loss {pct:5.2f} %")


if __name__ == "__main__":
    main()
