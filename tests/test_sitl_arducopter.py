"""The companion against ArduPilot's own ArduCopter SITL (issue 12): real processes on
127.0.0.1 — ``arducopter`` on a free instance, the companion on SERIAL0, plant-sim as the
camera only (``--pose-from``) on SERIAL1, a ground station on SERIAL2 — judged from
plant-sim's ground truth. Every wait is bounded; the children's logs are printed on
failure (pytest shows the captured output).

The binary comes from ``$ARDUCOPTER_SITL`` only (the real autopilot is opt-in: no binary
ships with this project). Without it the flights skip with one line saying how to get one,
under ``CI=true`` too; with it they run and must pass.

SITL runs at ``--speedup 3``: boot to EKF-using-GPS (~42 s of autopilot time), takeoff and
the 20 m leg take ~35 s of wall time per test on two loaded cores. The verdict at this
speed-up is the one at real time (``benchmarks/bench_sitl.py`` checks it).
"""

from __future__ import annotations

import os
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from evaluation.sil import _read_truth
from evaluation.sitl import (
    ARDUCOPTER_SITL_ENV,
    SITL_HOWTO,
    SitlOptions,
    SitlRig,
    find_arducopter_sitl,
    free_sitl_instance,
    run_sitl_sil,
)
from evaluation.sitl_scene import sitl_scene

M = mavlink
SPEEDUP = 3.0
CLEARANCE_M = 0.5  # from the sphere's surface to the vehicle's centre
LOITER, GUIDED = 5, 4


@pytest.fixture(scope="module")
def sitl_binary():
    binary = find_arducopter_sitl()
    if binary is None:
        pytest.skip(SITL_HOWTO)
    return binary


def test_the_sitl_binary_is_found_from_the_environment_first(tmp_path):
    fake = tmp_path / "arducopter"
    fake.write_text("#!/bin/sh\n")
    assert find_arducopter_sitl({ARDUCOPTER_SITL_ENV: str(fake)}) != fake.resolve()  # not +x
    fake.chmod(0o755)
    assert find_arducopter_sitl({ARDUCOPTER_SITL_ENV: str(fake)}) == fake.resolve()


def test_without_the_variable_no_binary_is_looked_for_anywhere_else():
    assert find_arducopter_sitl({}) is None
    assert find_arducopter_sitl({ARDUCOPTER_SITL_ENV: ""}) is None
    assert "Setting up SITL on Linux" in SITL_HOWTO and ARDUCOPTER_SITL_ENV in SITL_HOWTO


def test_a_free_sitl_instance_has_its_ports_free():
    n = free_sitl_instance()
    assert 0 <= n <= 255  # SITL keeps -I in 8 bits
    for port in range(5760 + 10 * n, 5764 + 10 * n):
        with socket.socket() as s:
            s.bind(("127.0.0.1", port))
    with pytest.raises(ValueError, match="bad SITL parameter"):
        SitlOptions(binary=Path("x"), params=(("wpnav speed", 1.0),))


def _print_logs(out_dir: Path, lines: list[str]) -> None:
    """Progress and the children's logs (kept in ``out_dir``); pytest shows them when the
    test fails."""
    print("\n".join(lines))
    for name in ("companion.log", "plant_sim.log", "arducopter_sitl.log"):
        path = Path(out_dir) / name
        if path.is_file():
            print(f"--- {name} (tail) ---\n{path.read_text(errors='replace')[-6000:]}")


def _fly(binary, out_dir, params=(), scene=None) -> object:
    lines: list[str] = []
    extra = {} if scene is None else {"scene": scene, "scene_name": "test-sitl"}
    try:
        return run_sitl_sil(
            SitlOptions(binary=binary, out_dir=out_dir, speedup=SPEEDUP, params=params, **extra),
            progress=lines.append,
        )
    finally:
        _print_logs(out_dir, lines)


@pytest.mark.slow
def test_paper_scene_on_arducopter_sitl_at_wpnav_speed_100(sitl_binary, tmp_path):
    """Takeoff by the companion at home to 7 m, goal 20 m north, the 1.5 m sphere 10 m
    north: with GUIDED targets flown at ≤ 1 m/s the companion side-steps the sphere."""
    result = _fly(sitl_binary, tmp_path, params=(("WPNAV_SPEED", 100.0),))
    v, fig = result.sil.verdict, result.figures
    print(v, fig)
    assert v.reached_goal and not v.collided, (v, fig)
    assert v.min_surface_distance_m >= CLEARANCE_M, (v, fig)
    assert v.avoidance_time_s > 0  # it did see and avoid the sphere
    assert fig["max_speed_mps"] <= 1.3  # WPNAV_SPEED 100 cm/s (+ the side-step)
    takeoff = fig["takeoff"]
    assert takeoff is not None and abs(takeoff["height_m"] - 7.0) <= 0.5
    truth = _read_truth(result.sil.truth_path)
    assert truth["pos_d_m"][0] == pytest.approx(0.0, abs=0.3)  # it started on the ground
    assert truth["armed"][0] == 0


@pytest.mark.slow
def test_paper_scene_on_arducopter_sitl_at_default_wpnav_speed(sitl_binary, tmp_path):
    """ArduCopter's default WPNAV_SPEED (10 m/s): without the safety envelope (issue 13)
    the companion flew through the sphere at 5.5 m/s; the carrot and the stated speed limit
    keep it clear."""
    result = _fly(sitl_binary, tmp_path)
    v, fig = result.sil.verdict, result.figures
    print(v, fig)
    assert v.reached_goal and not v.collided, (v, fig)
    assert v.min_surface_distance_m >= CLEARANCE_M, (v, fig)


#: Not the paper's scene: start facing away from the goal, 16 m south-west of the start
#: behind a 6 m wide, 8 m tall wall (a box, not a sphere) that reaches the ground.
WALL_BEHIND_SCENARIO = {
    "goal_ned_m": [0.0, 0.0, -6.0],
    "start": {"pos_ned_m": [16.0, 1.0, -6.0], "yaw_deg": 0.0},
    "obstacles": [{"shape": "box", "center_ned_m": [6.0, 0.0, -4.0], "size_m": [0.4, 6.0, 8.0]}],
}


@pytest.mark.slow
def test_a_scenario_of_its_own_on_arducopter_sitl_at_default_wpnav_speed(sitl_binary, tmp_path):
    """A plant-sim scenario file flown on ArduCopter (``sil --scenario``), moved so that its
    start is SITL's home: the vehicle starts facing away from the goal (SITL's start
    heading is the scenario's), looks before it moves, and goes round the wall at
    WPNAV_SPEED 10 m/s with the safety envelope."""
    scene = sitl_scene(WALL_BEHIND_SCENARIO)
    result = _fly(sitl_binary, tmp_path, scene=scene)
    v, fig = result.sil.verdict, result.figures
    print(v, fig)
    assert v.reached_goal and not v.collided, (v, fig)
    assert v.min_surface_distance_m >= CLEARANCE_M, (v, fig)
    truth = _read_truth(result.sil.truth_path)
    # SITL took the scenario's heading (north, away from the goal) before the takeoff
    assert abs(np.degrees(truth["yaw_rad"][0])) < 10.0, truth["yaw_rad"][0]
    # the goal is where the scenario put it, relative to the start at home
    assert v.final_goal_distance_m < 0.5
    assert scene.goal_ned_m == (-16.0, -1.0, -6.0)


@pytest.mark.slow
def test_a_goal_inside_an_obstacle_on_arducopter_sitl_ends_in_a_safe_reported_stop(
    sitl_binary, tmp_path
):
    """The goal inside a sphere: ArduCopter holds outside it, the companion reports the
    stop, and the run ends as soon as the vehicle is at rest (not at the time limit) with
    the lockstep's verdict: a safe stop, reason goal_unreachable.

    The reason is exact on purpose: a goal inside a confirmed boundary always ends in
    goal_unreachable, whichever of the obstacle's map pieces the frames confirmed first
    (guidance stops short of the whole obstacle; ``test_guidance_avoidance``). Under CPU
    load it once came out goal_inside_boundary, held 2.46 m out, when the stop point lay
    inside a front piece."""
    scene = sitl_scene(
        {"obstacles": [{"center_ned_m": [0.5, 0.0, -7.0], "radius_m": 1.5}]}  # goal (0, 0, -7)
    )
    result = _fly(sitl_binary, tmp_path, scene=scene)
    v = result.sil.verdict
    print(v)
    assert v.safe_stop and v.hold_reason == "goal_unreachable", v
    assert v.min_surface_distance_m >= CLEARANCE_M, v
    assert v.sim_time_s < 60.0, v  # ended at rest, not by the 120 s limit
    assert any(name == "hold" for name, _ in result.sil.events)


def _set_mode(gcs, custom_mode: int) -> None:
    gcs.mav.command_long_send(
        1,
        1,
        M.MAV_CMD_DO_SET_MODE,
        0,
        M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
        custom_mode,
        0,
        0,
        0,
        0,
        0,
    )


class Sticks:
    """A pilot's sticks centred (throttle mid: LOITER holds altitude) by RC_CHANNELS_OVERRIDE
    from the ground station at 4 Hz (ArduPilot drops an override after RC_OVERRIDE_TIME,
    3 s); SITL's own throttle input is at its minimum, which would descend in LOITER."""

    def __init__(self, gcs) -> None:
        self.gcs = gcs
        self.lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(0.25):
            with self.lock:
                self.gcs.mav.rc_channels_override_send(1, 1, 1500, 1500, 1500, 1500, *[0] * 4)

    def set_mode(self, custom_mode: int) -> None:
        with self.lock:
            _set_mode(self.gcs, custom_mode)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


def _wait_heartbeat_mode(gcs, custom_mode: int, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        msg = gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5)
        if msg is not None and msg.get_srcComponent() == 1 and msg.custom_mode == custom_mode:
            return
    raise AssertionError(f"autopilot not in mode {custom_mode} within {timeout_s} s")


def _wait_autopilot_time(truth_path: Path, seconds: float, timeout_s: float = 60.0) -> None:
    """Wait for ``seconds`` of autopilot time, read from plant-sim's truth log (SITL's own
    clock): on a loaded machine SITL runs below its ``--speedup``, so a wall-clock sleep of
    ``seconds / SPEEDUP`` may cover much less of its time."""
    start = None
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        t = _read_truth(truth_path).get("time_s") if truth_path.is_file() else None
        if t is not None and len(t):
            start = float(t[-1]) if start is None else start
            if float(t[-1]) - start >= seconds:
                return
        time.sleep(0.2)
    raise AssertionError(f"{seconds} s of autopilot time did not pass in {timeout_s} s of wall")


def _first_after(rig, n_before: int, phase: str, timeout_s: float = 20.0) -> dict:
    """The first ``phase`` event after the first ``n_before`` phase events."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for _ev, fields in rig.companion.events("phase")[n_before:]:
            if fields["phase"] == phase:
                return fields
        time.sleep(0.05)
    raise AssertionError(f"no phase {phase!r} within {timeout_s} s\n{rig.logs()}")


@pytest.mark.slow
def test_loiter_takeover_on_arducopter_sitl_releases_then_resumes_in_guided(sitl_binary, tmp_path):
    """A ground station on SERIAL2 switches to LOITER mid-flight: the companion stops
    steering (no setpoint while the pilot has it) and ArduCopter holds position; back in
    GUIDED the companion resumes and reaches the goal without a collision."""
    lines: list[str] = []
    options = SitlOptions(
        binary=sitl_binary, out_dir=tmp_path, speedup=SPEEDUP, params=(("WPNAV_SPEED", 100.0),)
    )
    gcs = sticks = None
    try:
        with SitlRig(options, progress=lines.append) as rig:
            try:
                rig.start()
                t0 = rig.wait_steering()
                gcs = mavutil.mavlink_connection(
                    rig.gcs_url(), source_system=255, source_component=190, dialect="ardupilotmega"
                )
                gcs.wait_heartbeat(timeout=10)
                sticks = Sticks(gcs)
                time.sleep(1.0)  # ~3 s of flight: well before the sphere is in range
                sticks.set_mode(LOITER)
                released = rig.wait_event("phase", 20, cond=lambda f: f["phase"] == "released")
                _wait_heartbeat_mode(gcs, LOITER, 10)
                _wait_autopilot_time(rig.out / "truth.csv", 8.0)  # 8 s of LOITER
                n_before = len(rig.companion.events("phase"))
                sticks.set_mode(GUIDED)
                resumed = _first_after(rig, n_before, "active")
                reached = rig.fly_to_goal()
            finally:
                if sticks is not None:
                    sticks.close()
                if gcs is not None:
                    gcs.close()
    finally:
        _print_logs(tmp_path, lines)  # the children's logs, written when the rig closed
    result = rig.judge()
    v = result.verdict
    print(v, released, resumed)
    assert released["mode"] == "LOITER"
    # not one setpoint between the release and the resume
    assert resumed["setpoints_sent"] == released["setpoints_sent"]
    assert reached and v.reached_goal and not v.collided, v
    assert v.min_surface_distance_m >= CLEARANCE_M, v
    truth = _read_truth(result.truth_path)
    rows = np.genfromtxt(result.truth_path, delimiter=",", names=True, dtype=None, encoding=None)
    loiter = rows["mode"] == "LOITER"
    assert loiter.sum() >= 5 * 50  # ≥ 5 s of LOITER at 50 rows/s
    t = truth["time_s"][loiter]
    assert t[0] > t0
    speed = np.hypot(truth["vel_n_mps"][loiter], truth["vel_e_mps"][loiter])
    late = t >= t[0] + 3.0  # ArduCopter's LOITER has stopped the vehicle by then
    assert np.max(speed[late]) < 0.3, speed[late]


def test_the_cli_without_a_binary_exits_2_and_says_how_to_get_one(tmp_path):
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != ARDUCOPTER_SITL_ENV}
    cmd = [sys.executable, "-m", "evaluation.cli", "sil", "--autopilot"]
    cmd += ["arducopter-sitl", "--out", str(tmp_path / "run")]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stdout + done.stderr
    assert "Setting up SITL on Linux" in done.stderr and ARDUCOPTER_SITL_ENV in done.stderr
