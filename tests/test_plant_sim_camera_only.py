"""plant-sim camera-only mode (``--pose-from``): the pose track, and the process against a
scripted MAVLink autopilot on loopback (no SITL needed; the ArduCopter SITL runs are in
``test_sitl_arducopter.py``)."""

from __future__ import annotations

import math
import socket
import time

import numpy as np
import pytest
import zenoh
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from evaluation.sil import ChildProcess, _read_truth, free_port
from plant_sim.__main__ import build_parser, config_from_args
from plant_sim.pose_track import PoseTrack
from protocols import stereo_frame
from protocols.frames import rotation_321
from protocols.keys import stereo_key

M = mavlink


# ---- the pose track (pure) ----------------------------------------------------------


def _feed(track: PoseTrack, t_s: float, vel=(2.0, 0.0, 0.0), yaw_rate=0.5) -> None:
    pos = tuple(v * t_s for v in vel)
    track.add_position(t_s, pos, vel)
    track.add_attitude(t_s, 0.0, 0.0, yaw_rate * t_s)


def test_frames_are_due_once_on_the_capture_grid_and_interpolated_exactly():
    track = PoseTrack(30.0)
    assert track.due_frames() == [] and track.at(1.0) is None
    due = []
    for k in range(51):  # 50 Hz samples from t = 1.0 s to 2.0 s
        _feed(track, 1.0 + k * 0.02)
        due += track.due_frames()
    expected = [i / 30.0 for i in range(30, 61)]
    np.testing.assert_allclose(due, expected, atol=1e-12)
    assert track.due_frames() == []  # each capture time once
    t = 47 / 30.0  # between two samples
    pose = track.at(t)
    np.testing.assert_allclose(pose.pos_ned_m, [2.0 * t, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(pose.R_ned_from_frd, rotation_321(0.0, 0.0, 0.5 * t), atol=1e-7)
    assert pose.roll_pitch_yaw_rad[2] == pytest.approx(0.5 * t, abs=1e-7)  # nlerp: 1e-7


def test_a_frame_waits_for_a_sample_after_it_never_extrapolates():
    track = PoseTrack(30.0)
    _feed(track, 0.0)
    _feed(track, 0.02)
    assert track.due_frames() == [0.0]  # 1/30 s is past the newest sample
    track.add_position(0.04, (0.08, 0, 0), (2, 0, 0))
    assert track.due_frames() == []  # attitude still at 0.02 s
    track.add_attitude(0.04, 0.0, 0.0, 0.02)
    assert track.due_frames() == pytest.approx([1 / 30.0])


def test_capture_times_inside_a_gap_are_skipped_and_counted():
    track = PoseTrack(30.0, max_gap_s=0.25)
    _feed(track, 0.0)
    _feed(track, 1.0)  # a 1 s gap (lost link)
    assert track.due_frames() == [0.0, 1.0]
    assert track.frames_skipped == 29


def test_a_huge_clock_jump_is_skipped_not_walked():
    track = PoseTrack(30.0)
    _feed(track, 0.0)
    _feed(track, 0.02)
    assert track.due_frames() == [0.0]
    _feed(track, 1e9)  # time_boot_ms jumps by 31 years
    t0 = time.monotonic()
    due = track.due_frames()
    assert time.monotonic() - t0 < 0.1
    assert due == [1e9] and track.frames_skipped > 10**10


def test_bad_samples_are_refused_never_crash():
    track = PoseTrack(30.0)
    assert not track.add_position(math.nan, (0, 0, 0), (0, 0, 0))
    assert not track.add_position(0.0, (0, math.inf, 0), (0, 0, 0))
    assert not track.add_attitude(0.0, math.nan, 0.0, 0.0)
    assert track.add_position(1.0, (0, 0, 0), (0, 0, 0))
    assert not track.add_position(1.0, (0, 0, 0), (0, 0, 0))  # not newer
    assert track.rejected == 4
    with pytest.raises(ValueError):
        PoseTrack(0.0)
    track.reset()
    assert track.newest_s is None


# ---- configuration ------------------------------------------------------------------


def test_pose_from_refuses_the_flags_of_its_own_autopilot():
    parse = build_parser().parse_args
    cfg = config_from_args(parse(["--pose-from", "tcp:127.0.0.1:5762", "--no-logs"]))
    assert cfg.pose_from == "tcp:127.0.0.1:5762" and cfg.offset_ned_m == (0.0, 0.0, 0.0)
    for extra in (["--speedup", "4"], ["--mavlink", "udpin:0.0.0.0:14550"], ["--duration", "5"]):
        with pytest.raises(ValueError, match="external autopilot"):
            config_from_args(parse(["--pose-from", "tcp:127.0.0.1:5762", *extra]))
    with pytest.raises(ValueError, match="signing is not supported"):
        config_from_args(parse(["--pose-from", "udpin:0.0.0.0:1", "--signing-key", "k"]))
    with pytest.raises(ValueError, match=r"pose_rate_hz: must be a finite number >= 30 Hz"):
        config_from_args(parse(["--pose-from", "udpin:0.0.0.0:1", "--pose-rate-hz", "10"]))


# ---- the process against a scripted autopilot --------------------------------------

# a straight flight north at 2 m/s and 7 m altitude, yawing slowly, past a sphere
SCENARIO = """
goal_ned_m = [20.0, 0.0, -7.0]
[[obstacles]]
center_ned_m = [10.0, 3.0, -7.0]
radius_m = 1.5
"""
OFFSET = (1.0, 0.0, 0.0)  # scenario = autopilot LOCAL_NED + (1, 0, 0)


def _position(t_s: float) -> tuple[float, float, float]:
    return (2.0 * t_s, 0.0, -7.0)


def test_camera_only_follows_an_external_autopilot(tmp_path):
    """A scripted autopilot streams LOCAL_POSITION_NED and ATTITUDE at the rate plant-sim
    asks for (SET_MESSAGE_INTERVAL); plant-sim publishes frames on the 30 Hz grid of the
    autopilot's boot clock, rendered from the pose at exactly that time, and logs the
    ground truth (distance to the sphere surface) in scenario coordinates."""
    (tmp_path / "scenario.toml").write_text(SCENARIO)
    ap_port = free_port()
    zen = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    ap = mavutil.mavlink_connection(
        f"udpin:127.0.0.1:{ap_port}", source_system=1, source_component=1, dialect="ardupilotmega"
    )
    plant = ChildProcess(
        "plant-sim",
        "plant_sim",
        [
            "--pose-from",
            f"udpout:127.0.0.1:{ap_port}",
            "--pose-offset-ned",
            *(str(x) for x in OFFSET),
            "--scenario",
            str(tmp_path / "scenario.toml"),
            "--zenoh-listen",
            zen,
            "--log-dir",
            str(tmp_path / "log"),
        ],
    )
    conf = zenoh.Config()
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", f'["{zen}"]')
    session = None
    frames: list[stereo_frame.StereoFrame] = []
    try:
        plant.wait_line(r"^PLANT_SIM READY mode=camera-only ", 60)
        session = zenoh.open(conf)
        sub = session.declare_subscriber(
            stereo_key("sim1"),
            lambda s: frames.append(stereo_frame.decode(bytes(s.payload.to_bytes()))),
        )
        intervals: dict[int, float] = {}
        their_heartbeat = None
        boot_ms = 100_000  # the autopilot booted 100 s ago
        t_fly = 0.0
        next_tx = time.monotonic()
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline and t_fly < 3.0:
            msg = ap.recv_match(blocking=True, timeout=0.005)
            if msg is not None:
                if msg.get_type() == "HEARTBEAT":
                    their_heartbeat = msg
                elif msg.get_type() == "COMMAND_LONG" and msg.command == 511:
                    intervals[round(msg.param1)] = msg.param2
                    ap.mav.command_ack_send(511, 0, 0, 0, msg.get_srcSystem(), 100)
            if their_heartbeat is None or time.monotonic() < next_tx:
                continue
            next_tx += 0.02
            ap.mav.heartbeat_send(
                M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_ARDUPILOTMEGA, 129 + 64, 4, 4
            )
            rate_ok = intervals.get(32, 1e9) <= 1e6 / 30 and intervals.get(30, 1e9) <= 1e6 / 30
            if not rate_ok:
                continue  # stream only once asked, like an autopilot
            ms = boot_ms + round(t_fly * 1000)
            n, e, d = _position(t_fly)
            ap.mav.local_position_ned_send(ms, n, e, d, 2.0, 0.0, 0.0)
            ap.mav.attitude_send(ms, 0.0, -0.05, 0.1 * t_fly, 0.0, 0.0, 0.0)
            t_fly += 0.02
        assert t_fly >= 3.0, plant.logs()
        # the last poses may still become frames (a loaded machine): until none came for 1 s
        seen, quiet_since, deadline = len(frames), time.monotonic(), time.monotonic() + 10.0
        while time.monotonic() - quiet_since < 1.0 and time.monotonic() < deadline:
            time.sleep(0.05)
            if len(frames) != seen:
                seen, quiet_since = len(frames), time.monotonic()
        sub.undeclare()
    finally:
        if session is not None:
            session.close()
        plant.stop()
        ap.close()
        log = plant.logs()
        plant.close()
    # it is a camera component, not an autopilot
    assert their_heartbeat.type == M.MAV_TYPE_CAMERA, log
    assert their_heartbeat.autopilot == M.MAV_AUTOPILOT_INVALID
    assert intervals[32] == pytest.approx(20_000) and intervals[30] == pytest.approx(20_000)
    assert len(frames) >= 80, log  # 3 s at 30 Hz
    t_cap = np.array([f.capture_ns for f in frames]) * 1e-9
    k = t_cap * 30.0
    np.testing.assert_allclose(k, np.round(k), atol=1e-6)  # on the 30 Hz grid
    assert np.all(np.diff(t_cap) > 0)
    assert t_cap[0] >= 100.0 and t_cap[-1] <= 103.0  # the autopilot's boot clock
    # ground truth at the same instants, in scenario coordinates (offset applied)
    truth = _read_truth(tmp_path / "log" / "truth.csv")
    t = truth["time_s"]
    assert len(t) >= 140, log
    fly = t - 100.0
    np.testing.assert_allclose(truth["pos_n_m"], 2.0 * fly + OFFSET[0], atol=1e-3)
    np.testing.assert_allclose(truth["yaw_rad"], 0.1 * fly, atol=1e-4)
    expected = np.sqrt((2.0 * fly + 1.0 - 10.0) ** 2 + 3.0**2) - 1.5
    np.testing.assert_allclose(truth["surface_distance_m"], expected, atol=1e-3)
    assert set(np.unique(truth["armed"])) == {1.0}
    assert np.all(np.isnan(truth["rotor1_n"]))  # unknown: left empty, never invented
    stats = plant.stats("PLANT_SIM STATS ")
    assert stats["mode"] == "camera-only" and stats["frames_published"] == len(frames)
    assert stats["latency_ms"]["pose_to_frame_p99"] is not None
