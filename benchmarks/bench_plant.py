"""Real-time factor of the plant's physics + flight control (issue 2 benchmark).

Prints figures; asserts nothing. Run: ``.venv/bin/python benchmarks/bench_plant.py``.
"""

from __future__ import annotations

import math
import time

from plant_sim.vehicle import Quadrotor, Setpoint


def _rtf(chunk_steps: int, sim_s: float) -> tuple[float, float]:
    q = Quadrotor(pos_ned_m=(20.0, 0.0, -7.0))
    q.set_setpoint(Setpoint(pos_ned_m=(0.0, 0.0, -7.0), yaw_rad=math.pi))
    q.step(chunk_steps)  # compile / warm up
    n_chunks = max(1, round(sim_s / (chunk_steps * q.dt_s)))
    t0 = time.perf_counter()
    for _ in range(n_chunks):
        q.step(chunk_steps)
    wall = time.perf_counter() - t0
    sim = n_chunks * chunk_steps * q.dt_s
    return sim / wall, wall / (n_chunks * chunk_steps) * 1e6


def main() -> None:
    q = Quadrotor()
    c = q.control
    print(f"physics {c.physics_rate_hz:.0f} Hz RK4, control {c.control_rate_hz:.0f} Hz")
    for label, chunk in (
        ("one step per call (worst case)", 1),
        ("one camera frame per call (30 Hz)", round(q.control.physics_rate_hz / 30)),
        ("1 s per call", round(q.control.physics_rate_hz)),
    ):
        rtf, us = _rtf(chunk, sim_s=60.0 if chunk > 1 else 20.0)
        print(f"{label:36s}: {us:7.2f} µs/step  real-time factor {rtf:8.0f}x")


if __name__ == "__main__":
    main()
