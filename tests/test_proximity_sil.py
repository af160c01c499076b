"""OBSTACLE_DISTANCE with real processes (issue 34): plant-sim as ArduCopter / PX4 and the
companion as a proximity sensor the autopilot trusts.

plant-sim forwards what the companion sends to the other peers, as a MAVLink router does
for a ground station, so the test's own client sees the companion's messages as they
reach the autopilot. Every process on 127.0.0.1 with free ports and explicit Zenoh
endpoints; every wait bounded; the children's logs printed on failure.
"""

from __future__ import annotations

import contextlib
import itertools
import socket
import time
from collections.abc import Iterator

import pytest
from _plant_sim_proc import PlantProcess, command, connect, recv
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from evaluation.sil import ChildProcess, free_port

M = mavlink
ARM = M.MAV_CMD_COMPONENT_ARM_DISARM
COMPANION = 196  # MAV_COMP_ID_OBSTACLE_AVOIDANCE

_ON_THE_GROUND = """\
[start]
pos_ned_m = [20.0, 0.0, -7.0]
airborne = false
mode = "LOITER"
"""


@contextlib.contextmanager
def _companion(mav_port: int, *args: str) -> Iterator[ChildProcess]:
    """A companion that only reports (it never asks for a mode), on its own Zenoh port."""
    zenoh = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    child = ChildProcess(
        "companion",
        "companion",
        ["--mavlink", f"udpout:127.0.0.1:{mav_port}", "--zenoh-listen", zenoh,
         "--no-request-mode", *args],
    )  # fmt: skip
    try:
        child.wait_line(r"^COMPANION READY ", 60)
        yield child
    finally:
        child.stop()
        print(child.logs())  # shown only when the test fails
        child.close()


def _set_param(m, name: str, value: float) -> None:
    m.mav.param_set_send(1, 1, name.encode(), float(value), M.MAV_PARAM_TYPE_REAL32)
    echo = recv(m, "PARAM_VALUE", 5.0, cond=lambda p: p.param_id == name)
    assert echo is not None and echo.param_value == pytest.approx(value), name


def _param(m, name: str) -> float:
    m.mav.param_request_read_send(1, 1, name.encode(), -1)
    echo = recv(m, "PARAM_VALUE", 5.0, cond=lambda p: p.param_id == name)
    assert echo is not None, name
    return float(echo.param_value)


def _arm(m):
    return command(m, ARM, 1)


def _obstacle_distance_times(m, seconds: float) -> tuple[list[float], list]:
    """Receipt times [s wall] and messages of the companion's OBSTACLE_DISTANCE."""
    times, msgs = [], []
    deadline = time.monotonic() + seconds
    while (left := deadline - time.monotonic()) > 0:
        msg = m.recv_match(type="OBSTACLE_DISTANCE", blocking=True, timeout=left)
        if msg is not None and msg.get_srcComponent() == COMPANION:
            times.append(time.monotonic())
            msgs.append(msg)
    return times, msgs


def test_prx1_arming_needs_the_companion_and_its_message_flows_before_takeoff(
    plant_factory, tmp_path
):
    """PRX1_TYPE = 2: refused with "PRX1: No Data" without the companion; with it running
    (no camera: all sectors unknown) OBSTACLE_DISTANCE arrives at >= 10 Hz before arming,
    arming passes; the companion stopped, 0.5 s later arming is refused again."""
    scenario = tmp_path / "ground.toml"
    scenario.write_text(_ON_THE_GROUND, encoding="utf-8")
    plant = plant_factory("--no-camera", "--scenario", str(scenario))
    m = connect(plant)
    _set_param(m, "PRX1_TYPE", 2)
    m.mav.command_long_send(1, 1, ARM, 0, 1, 0, 0, 0, 0, 0, 0)
    text = recv(m, "STATUSTEXT", 3.0, cond=lambda t: "PRX1" in t.text)  # before the ACK
    assert text is not None and text.text.startswith("Arm: PRX1: No Data"), text
    ack = recv(m, "COMMAND_ACK", 3.0, cond=lambda a: a.command == ARM)
    assert ack is not None and ack.result == M.MAV_RESULT_FAILED
    with _companion(plant.mavlink_port) as companion:
        # by default from a process of its own, through the companion's socket
        assert "OBSTACLE_DISTANCE process sending through the companion's socket" in (
            companion.stderr_text()
        )
        times, msgs = _obstacle_distance_times(m, 3.0)
        assert len(times) >= 20, f"{len(times)} OBSTACLE_DISTANCE in 3 s"
        rate_hz = (len(times) - 1) / (times[-1] - times[0])
        gaps = [b - a for a, b in itertools.pairwise(times)]
        assert rate_hz >= 10.0 and max(gaps) < 0.5, (rate_hz, max(gaps))
        for msg in msgs:
            assert msg.frame == M.MAV_FRAME_BODY_FRD and msg.increment_f == 5.0
            assert list(msg.distances) == [65535] * 72  # no camera: unknown, never clear
        ack = _arm(m)
        assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED, ack
        print(f"OBSTACLE_DISTANCE before arming: {rate_hz:.1f} Hz, max gap {max(gaps):.3f} s")
        assert command(m, ARM, 0).result == M.MAV_RESULT_ACCEPTED
    time.sleep(0.6)  # the proximity driver's 0.5 s timeout (a wall-time rule)
    ack = _arm(m)
    assert ack is not None and ack.result == M.MAV_RESULT_FAILED
    stats = plant.stop()
    assert stats is not None and stats["obstacle_distance_received"] >= 20


# ---- pilot-flown approaches: the autopilot's own avoidance on the companion's map ------

SPEEDUP = 1.0
START_N_M = 20.0  # the paper's start, facing south toward the obstacle at 10 m
_SCENES = {
    "sphere": "center_ned_m = [10.0, 0.0, -7.0]\nradius_m = 1.5\n",  # the paper's §6
    "wall": 'shape = "box"\ncenter_ned_m = [10.0, 0.0, -7.0]\nsize_m = [0.2, 30.0, 14.0]\n'
    'material = "{material}"\n',
}
_APPROACH = """\
profile = "fast"
goal_ned_m = [0.0, 0.0, -7.0]

[start]
pos_ned_m = [{start}, 0.0, -7.0]
yaw_deg = 180.0
airborne = true
mode = "{mode}"

[[obstacles]]
{obstacle}"""


def _start_n_m(flavour: str, speed_mps: float) -> float:
    """Where the approach starts [m north]: the paper's start at 2 m/s and for PX4 (its
    Collision Prevention caps the speed to what stops within the sensor's reach, and it
    does not move toward sectors without data: from farther away the wall's texture is
    too fine to match); ArduCopter faster, far enough that the vehicle has reached the
    speed and levelled to its cruise pitch before the obstacle is within the sensor's
    16 m reach (LOITER takes about 2.5 m/s² on average and overshoots; pitched 30° while
    it accelerates, the camera cannot see its own altitude ahead), and no farther: each
    second is a second of the suite."""
    if flavour == "px4" or speed_mps <= 2.0:
        return START_N_M
    return 11.5 + 16.0 + speed_mps**2 / (2.0 * 2.5) + 3.0


def _pilot_approach(
    tmp_path,
    flavour: str,
    scene: str,
    speed_mps: float,
    material="textured",
    *,
    lean_deg: float | None = None,
    sim_s: float | None = None,
    params: dict[str, float] | None = None,
):
    """Fly straight at the obstacle with the pitch stick held (MANUAL_CONTROL) in LOITER
    (PX4: Position mode) while the companion only reports; returns the truth log. With
    ``lean_deg`` (ArduCopter) the vehicle flies ALT_HOLD with the stick at that forward
    lean, ``speed_mps`` then being its expected average speed (the run's length)."""
    from evaluation.sil import _read_truth

    start_n_m = START_N_M if lean_deg is not None else _start_n_m(flavour, speed_mps)
    surface_m = start_n_m - (11.5 if scene == "sphere" else 10.1)
    sim_s = sim_s or 6.0 + surface_m / speed_mps
    scenario = tmp_path / "approach.toml"
    obstacle = _SCENES[scene].format(material=material)
    mode = "LOITER" if lean_deg is None else "ALT_HOLD"
    scenario.write_text(
        _APPROACH.format(start=start_n_m, obstacle=obstacle, mode=mode), encoding="utf-8"
    )
    mav_port = free_port()
    plant_zenoh = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    companion_zenoh = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    with contextlib.ExitStack() as stack:
        # OBSTACLE_DISTANCE from its own process (the default on a UDP link)
        companion = stack.enter_context(_companion_at(mav_port, companion_zenoh))
        plant = PlantProcess(
            ["--scenario", str(scenario), "--mavlink", f"udpin:127.0.0.1:{mav_port}",
             "--zenoh-listen", plant_zenoh, "--zenoh-connect", companion_zenoh,
             "--speedup", f"{SPEEDUP:g}", "--duration", f"{sim_s:g}",
             "--log-dir", str(tmp_path / "run"), "--autopilot-flavour", flavour],
        )  # fmt: skip
        stack.callback(plant.close)
        stack.callback(lambda: print(plant.logs()))
        plant.wait_ready()
        m = connect(plant)
        stick = 1.0
        if flavour == "px4":
            _set_param(m, "CP_DIST", 2.0)
            top = max(speed_mps, 3.0)  # MPC_VEL_MANUAL's minimum is 3 m/s
            _set_param(m, "MPC_VEL_MANUAL", top)
            stick = speed_mps / top
            ack = command(m, M.MAV_CMD_DO_SET_MODE, 1, 3, 0)  # POSCTL
            assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
        else:
            _set_param(m, "PRX1_TYPE", 2)
            # The sectors come from a map that already needs two frames to make an
            # obstacle: ArduPilot's own 0.25 Hz face filter (PRX_FILT) would only delay
            # them, v / (2π · 0.25 Hz) = 1.3 m at 2 m/s (docs/autopilots.md), so it is off.
            _set_param(m, "PRX_FILT", 0.0)
            if lean_deg is None:
                _set_param(m, "LOIT_SPEED", speed_mps * 100.0)
            else:  # full stick is ANGLE_MAX
                stick = lean_deg / (_param(m, "ANGLE_MAX") / 100.0)
        for name, value in (params or {}).items():
            _set_param(m, name, value)
        x = round(1000.0 * (0.04 + 0.96 * stick))  # past the 20 µs dead band
        deadline = time.monotonic() + 3.0 * sim_s / SPEEDUP + 60.0
        seen = []  # (vehicle north [m], nearest sector [m] or None) per OBSTACLE_DISTANCE
        north = start_n_m
        next_stick = 0.0
        while plant.proc.poll() is None and time.monotonic() < deadline:
            if time.monotonic() >= next_stick:
                m.mav.manual_control_send(1, x, 0, 500, 0, 0)  # the pilot's stick, 20 Hz
                next_stick = time.monotonic() + 0.05
            msg = m.recv_match(
                type=["OBSTACLE_DISTANCE", "LOCAL_POSITION_NED"], blocking=True, timeout=0.05
            )
            if msg is None:
                continue
            if msg.get_type() == "LOCAL_POSITION_NED":
                north = msg.x
            elif msg.get_srcComponent() == COMPANION:
                near = [d for d in msg.distances[:72] if d <= msg.max_distance]
                seen.append((north, min(near) / 100.0 if near else None, time.monotonic()))
        assert plant.proc.poll() is not None, "plant-sim did not finish its run"
        stats = plant.stop()
        assert stats is not None and stats["obstacle_distance_received"] > 0
        assert companion.proc.poll() is None, "the companion died"
        assert not companion.events("steering"), "the companion must only report"
        truth = _read_truth(tmp_path / "run" / "truth.csv")
        print(f"{flavour} {scene} {speed_mps} m/s: min surface distance "
              f"{truth['surface_distance_m'].min():.2f} m, avoidance ticks "
              f"{stats['avoidance_limited_ticks']}, flown without fresh proximity data "
              f"{stats['proximity_stale_ticks']} ticks")  # fmt: skip
        moving = truth["vel_n_mps"] < -0.5  # flying south, toward the obstacle
        if moving.any():  # where the first approach came to rest: the stop itself
            first = int(moving.argmax())
            stopped = truth["vel_n_mps"][first:] >= 0.0
            if stopped.any():
                rest = first + int(stopped.argmax())
                print(f"  first stop {truth['surface_distance_m'][rest]:.2f} m from the surface")
        gaps = [b[2] - a[2] for a, b in itertools.pairwise(seen)]
        print(f"  OBSTACLE_DISTANCE: {len(seen)}, longest gap {max(gaps):.3f} s (wall)")
        for n, near, t in seen[:: max(1, len(seen) // 80)]:
            print(f"  {t:.2f} north {n:6.2f} m: nearest sector {near}")
        return truth, stats, seen


@contextlib.contextmanager
def _companion_at(mav_port: int, zenoh: str) -> Iterator[ChildProcess]:
    child = ChildProcess(
        "companion",
        "companion",
        ["--mavlink", f"udpout:127.0.0.1:{mav_port}", "--zenoh-listen", zenoh,
         "--no-request-mode"],
    )  # fmt: skip
    try:
        child.wait_line(r"^COMPANION READY ", 60)
        yield child
    finally:
        child.stop()
        print(child.logs())
        child.close()


# At 8 m/s (issue 34): with the watchdog thread 18 of 20 runs at load 11-24 held, the two
# that did not were stalls of the stream and of plant-sim. With the stream in its own
# real-time process (fourth pass) its longest gap was <= 0.079 s, yet 4 of 19 flights at
# load 14-22 did not hold: the companion's main loop (perception) was starved for
# seconds. Fifth pass, the process sending through the companion's socket with the pose
# the main loop shares (on by default): 10 of 12 held at load 18-24 (3 runs per case
# beside 3 spinning processes); the process's longest gap was <= 0.082 s in every run
# and plant-sim's autopilot never flew without fresh data; the two ArduCopter failures
# (-1.47 m, 0.66 m, load 23-24) came with 2.0 s main-loop stalls, in which the map did
# not move on and the shared pose went stale (sectors sent unknown) (docs/autopilots.md).
# Sixth pass, the process as the socket's only reader (its own pose, every datagram
# forwarded): 16 of 18 held (3 runs per case beside 3 spinning processes, load 12-16.5;
# 3 ArduCopter runs per scene beside 6, load 13-18, one of them through a 2.94 s
# main-loop stall at 2.11 m). The two that did not (ArduCopter sphere, first stop 1.65
# and 1.49 m) had the stream and a fresh pose throughout (plant-sim 0 ticks without
# fresh data, no stale send in flight, no take-over): the sphere entered the sectors
# 11-12.6 m ahead, against 14.9-16.2 m in the run that held at the same load (the map,
# from a main loop processing 133-160 of 300 frames, was late). Seventh pass, guidance,
# planning, the envelope and the hold's way out skipped while the companion only
# reports (about 12 % of a frame's CPU): 15 of 15 held, 2.11-2.34 m (3 runs per case at
# load 15-21, 3 more ArduCopter sphere runs beside 3 spinning processes at load 20-26),
# the obstacle first in the sectors 14.6-15.7 m ahead of ArduCopter; no longer an xfail
# (docs/autopilots.md).


@pytest.mark.slow
@pytest.mark.parametrize(
    ("flavour", "scene"),
    [
        ("ardupilot", "sphere"),
        ("ardupilot", "wall"),
        ("px4", "sphere"),
        ("px4", "wall"),
    ],
)
@pytest.mark.parametrize("speed_mps", [2.0, 5.0, 8.0])
def test_pilot_flown_approach_stops_outside_the_margin(tmp_path, flavour, scene, speed_mps):
    """AVOID_MARGIN 2 m (ArduCopter LOITER) / CP_DIST 2 m (PX4 Position mode): the
    vehicle stops at least 1.7 m from the surface with the companion only reporting."""
    truth, _, _ = _pilot_approach(tmp_path, flavour, scene, speed_mps)
    surface = truth["surface_distance_m"]
    assert surface.min() >= 2.0 - 0.3, surface.min()
    travelled = _start_n_m(flavour, speed_mps) - truth["pos_n_m"].min()
    assert travelled > 3.0, "the pilot's stick moved the vehicle toward the obstacle"


@pytest.mark.slow
@pytest.mark.parametrize("flavour", ["ardupilot", "px4"])
def test_textureless_wall_is_unknown_px4_holds_and_ardupilot_flies_on(tmp_path, flavour):
    """A textureless wall is never matched: the companion reports its sectors unknown
    (UINT16_MAX), never clear. PX4 (CP_GO_NO_DATA 0) refuses to move into them; ArduPilot
    ignores unknown sectors as it ignores clear ones (AP_Proximity_MAV drops UINT16_MAX),
    so its simple avoidance does not stop the pilot: documented, not a plant-sim bug."""
    # PX4 does not move at all: 5 s of held stick show it (ArduCopter needs its 11 s)
    sim_s = 5.0 if flavour == "px4" else None
    truth, _, seen = _pilot_approach(
        tmp_path, flavour, "wall", 2.0, material="textureless", sim_s=sim_s
    )
    surface = truth["surface_distance_m"]
    near_wall = [near for n, near, _ in seen if n - 10.1 < 4.0]  # within 4 m of the wall
    if flavour == "px4":
        assert surface.min() >= 2.0 - 0.3, surface.min()
        # the held stick (2 m/s: 8 m in 4 s) did not move it toward the unknown
        assert START_N_M - truth["pos_n_m"].min() < 0.5, truth["pos_n_m"].min()
    else:
        assert near_wall, "the vehicle came within 4 m of the wall"
        assert surface.min() < 1.0, "ArduPilot has no reading to stop on"
    # the wall is never reported as a near obstacle: no sector within 2 m of the vehicle
    assert all(near is None or near > 2.5 for near in near_wall), near_wall


@pytest.mark.slow
def test_pilot_flown_alt_hold_is_leaned_away_from_the_sphere(tmp_path):
    """ALT_HOLD, the pilot leaning 5° toward the paper's sphere (1.9 m/s on the fast
    airframe's drag): ArduCopter's AC_Avoid::adjust_roll_pitch leans it back by
    45°·(1 − d/AVOID_DIST_MAX), capped at AVOID_ANGLE_MAX 10°. The two cancel at
    d = 5·(1 − 5/45) = 4.4 m; with no margin and no stopping distance the vehicle coasts
    past that on its speed, is pushed back with the stick still held, and never comes near
    the surface (a lean over 10° would fly on: the pilot can override, by design)."""
    lean_deg = 5.0
    # 1.5 m/s: its average speed from rest toward a terminal 1.9 m/s (the run's length)
    truth, stats, _ = _pilot_approach(tmp_path, "ardupilot", "sphere", 1.5, lean_deg=lean_deg)
    assert stats["avoidance_limited_ticks"] > 0
    surface, north = truth["surface_distance_m"], truth["pos_n_m"]
    closest = int(surface.argmin())
    balance_m = 5.0 * (1.0 - lean_deg / 45.0)
    assert START_N_M - north.min() > 3.0, "the lean moved the vehicle toward the sphere"
    assert 2.0 <= surface[closest] < balance_m, surface[closest]
    # pushed back with the stick held: it moves away from its closest point
    assert north[closest:].max() > north[closest] + 0.3, north[closest:].max()
