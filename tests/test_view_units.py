"""Recording and viewing, in process: geometry closed forms, observers, record → replay.

The record → replay round trip here runs the lockstep plant in process and feeds the
recorder the same hook calls the service makes; the networked SIL round trip is in
``test_view_sil.py``.
"""

from __future__ import annotations

import json
import logging
import math

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.config import CompanionConfig, build_parser, config_from_args
from companion.guidance import GuidanceConfig
from companion.observe import CompanionObserver, Observers, TappedLink
from companion.perception import PerceptionConfig
from companion.pipeline import AvoidancePipeline
from companion.pose_history import PoseHistory
from companion.record import format as fmt
from companion.record.recorder import McapRecorder
from companion.record.replay import RecordingError, replay
from companion.viz.options import ViewOptionError, observers_from_args
from companion.viz.rerun_log import RerunTarget
from companion.viz.scene_geometry import (
    CLASS_NEAR,
    CLASS_UNKNOWN,
    CLASS_VALID,
    cone_lines_ned_m,
    depth_classes,
    near_points_ned_m,
    velocity_in_cone,
)
from plant_sim.stereo_camera import StereoCameraRenderer
from plant_sim.world import paper_world
from protocols.camera import CameraModel
from protocols.frames import rotation_321

# ---- geometry ---------------------------------------------------------------------------


def test_cone_circle_is_the_tangent_circle():
    apex = np.array([20.0, 0.0, -7.0])
    centre = np.array([10.0, 1.0, -7.5])
    r = 1.85
    lines = cone_lines_ned_m(apex, centre, r, n_circle=64, n_rays=8)
    circle, rays = lines[0], lines[1:]
    d = np.linalg.norm(centre - apex)
    # every tangent point: on the sphere, at the tangent length from the apex, and the
    # radius there is perpendicular to the line of sight (tangency)
    np.testing.assert_allclose(np.linalg.norm(circle - centre, axis=1), r, rtol=1e-12)
    np.testing.assert_allclose(
        np.linalg.norm(circle - apex, axis=1), math.sqrt(d * d - r * r), rtol=1e-12
    )
    np.testing.assert_allclose(np.einsum("ij,ij->i", circle - centre, circle - apex), 0, atol=1e-9)
    np.testing.assert_allclose(circle[0], circle[-1], atol=1e-12)  # closed
    assert len(rays) == 8
    for ray in rays:
        np.testing.assert_allclose(ray[0], apex)
        np.testing.assert_allclose(np.linalg.norm(ray[1] - centre), r, rtol=1e-12)


def test_no_cone_from_inside_the_sphere():
    assert cone_lines_ned_m([0.0, 0.0, 0.0], [0.5, 0.0, 0.0], 1.0) == []


def test_velocity_in_cone_at_the_half_angle():
    apex, centre, r = np.zeros(3), np.array([10.0, 0.0, 0.0]), 2.0
    half = math.asin(r / 10.0)
    for angle, inside in ((0.0, True), (half - 1e-6, True), (half + 1e-6, False)):
        v = np.array([math.cos(angle), math.sin(angle), 0.0])
        assert velocity_in_cone(apex, v, centre, r) is inside, angle
    assert not velocity_in_cone(apex, [-1.0, 0.0, 0.0], centre, r)
    assert not velocity_in_cone(apex, [0.0, 0.0, 0.0], centre, r)


def test_depth_classes():
    depth = np.array([[1.0, 5.0, np.nan, np.inf, 3.999]])
    assert depth_classes(depth, 4.0).tolist() == [
        [CLASS_NEAR, CLASS_VALID, CLASS_UNKNOWN, CLASS_VALID, CLASS_NEAR]
    ]


def test_near_points_back_project_into_ned():
    k = CameraModel().intrinsics
    depth = np.full((k.height_px, k.width_px), 2.0)
    pos = np.array([20.0, 0.0, -7.0])
    R = rotation_321(0.0, 0.0, math.pi)  # facing south
    pts = near_points_ned_m(depth, 4.0, k, pos, R, stride_px=1)
    assert pts.shape == (k.width_px * k.height_px, 3)
    # a plane 2 m ahead (south) of the camera: north = 18 everywhere
    np.testing.assert_allclose(pts[:, 0], 18.0, atol=1e-12)
    # pixel (u, v) at depth z: body FRD (z, (u - cx) z / fx - b/2, (v - cy) z / fy); facing
    # south, NED = (20 - forward, -right, -7 + down)
    u, v = 159, 119
    right = (u - k.cx_px) * 2.0 / k.fx_px - k.baseline_m / 2.0
    down = (v - k.cy_px) * 2.0 / k.fy_px
    np.testing.assert_allclose(pts[v * k.width_px + u], [18.0, -right, -7.0 + down], atol=1e-12)
    assert near_points_ned_m(depth, 1.0, k, pos, R).shape == (0, 3)  # none nearer than 1 m


# ---- options and observers -----------------------------------------------------------------


def test_rerun_target_parse():
    assert RerunTarget.parse("run.rrd").path.name == "run.rrd"
    t = RerunTarget.parse("serve")
    assert (t.web_port, t.grpc_port) == (9090, 9091)
    assert RerunTarget.parse("serve:8000").web_port == 8000
    for bad in ("run.txt", "serve:x", "serve:0", "serve:70000"):
        with pytest.raises(ValueError, match="--rerun"):
            RerunTarget.parse(bad)


def test_view_options(tmp_path):
    assert observers_from_args(None, None) == []
    with pytest.raises(ViewOptionError, match=r"FILE\.mcap"):
        observers_from_args(tmp_path / "x.bag", None)
    with pytest.raises(ViewOptionError, match="does not exist"):
        observers_from_args(tmp_path / "missing" / "x.mcap", None)
    (rec,) = observers_from_args(tmp_path / "x.mcap", None)
    assert isinstance(rec, McapRecorder)
    args = build_parser().parse_args(["--record", str(tmp_path / "x.mcap"), "--rerun", "serve"])
    assert args.record == tmp_path / "x.mcap" and args.rerun == "serve"
    config_from_args(args)  # the flags are not config: the config still builds


def test_companion_refuses_bad_view_flags(tmp_path, capsys):
    from companion.__main__ import main

    assert main(["--record", str(tmp_path / "x.txt")]) == 2
    assert "--record takes FILE.mcap" in capsys.readouterr().err
    assert main(["--rerun", "x.png"]) == 2
    assert "--rerun takes FILE.rrd" in capsys.readouterr().err


class _Boom(CompanionObserver):
    def on_frame(self, frame, recv_ns):
        raise RuntimeError("bug")


class _Count(CompanionObserver):
    def __init__(self):
        self.frames = 0
        self.out = []

    def on_frame(self, frame, recv_ns):
        self.frames += 1

    def on_mavlink_out(self, msg, sent_ns):
        self.out.append(msg)


def test_observers_fan_out_and_contain_failures(caplog):
    assert not Observers()  # the service's guard: no observers, no calls
    count = _Count()
    obs = Observers([_Boom(), count])
    assert obs and len(obs) == 2
    with caplog.at_level(logging.ERROR, logger="companion.observe"):
        for _ in range(3):
            obs.on_frame(None, 0)
    assert count.frames == 3  # the failing observer does not starve the next one
    assert len([r for r in caplog.records if "_Boom.on_frame failed" in r.message]) == 1


class _Link:
    def __init__(self, ok):
        self.ok = ok
        self.url = "udpout:x"

    def send(self, msg):
        return self.ok


def test_tapped_link_reports_only_sent_messages():
    count = _Count()
    ok, failing = TappedLink(_Link(True), count), TappedLink(_Link(False), count)
    assert ok.url == "udpout:x"  # everything else is the link's
    assert ok.send("a") and not failing.send("b")
    assert count.out == ["a"]


def test_config_round_trip_through_a_recording():
    config = CompanionConfig(
        waypoints_ned_m=((5.0, 1.0, -3.0), (0.0, 0.0, -7.0)),
        perception=PerceptionConfig(threshold_m=5.0, safety_margin_m=0.4),
        guidance=GuidanceConfig.from_dict({}),
    )
    text = json.dumps(fmt.config_to_dict(config))
    assert "signing" not in text
    back = fmt.config_from_recorded(text)
    for name in ("waypoints_ned_m", "perception", "guidance", "known_space", "envelope"):
        assert getattr(back, name) == getattr(config, name), name
    assert back.link.frame_clock is config.link.frame_clock


# ---- record → replay, in process -----------------------------------------------------------


def _fly_and_record(path, n_frames=24, tamper=None):
    """The service's hook sequence for a short flight toward the paper's obstacle: MAVLink
    telemetry in, decoded (float32 on the wire) into a pose history as the service does,
    a frame, the pipeline at the interpolated pose, the setpoint out; recorded to ``path``."""
    config = CompanionConfig()
    recorder = McapRecorder(path)
    recorder.on_start(config)
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    mav_us = mavlink.MAVLink(None, srcSystem=1, srcComponent=196)
    wire = mavlink.MAVLink(None)
    poses = PoseHistory()
    renderer = StereoCameraRenderer(CameraModel())
    world = paper_world()
    pipeline = AvoidancePipeline(config.waypoints_ned_m[0])
    speed = 1.0
    now_s = 100.0
    sent = []
    for i in range(n_frames):
        t_s = 1.0 + i / 30.0
        # telemetry bracketing the frame (ms resolution: the frame is stamped on a ms)
        for dt in (-0.02, 0.0, 0.02):
            tb = t_s + dt
            pos = (14.0 - speed * tb, 0.0, -7.0)
            boot_ms = round(tb * 1000)
            for msg in (
                mavlink.MAVLink_local_position_ned_message(boot_ms, *pos, -speed, 0.0, 0.0),
                mavlink.MAVLink_attitude_message(boot_ms, 0.0, 0.0, math.pi, 0, 0, 0),
            ):
                (got,) = wire.parse_buffer(msg.pack(mav))
                recorder.on_mavlink_in(got, now_s, 1.0)
                if got.get_type() == "ATTITUDE":
                    poses.add_attitude(boot_ms * 1_000_000, got.roll, got.pitch, got.yaw)
                else:
                    p_v = (got.x, got.y, got.z), (got.vx, got.vy, got.vz)
                    poses.add_position(boot_ms * 1_000_000, *p_v)
            now_s += 0.001
        capture_ns = round(t_s * 1000) * 1_000_000
        pos = np.array([14.0 - speed * capture_ns * 1e-9, 0.0, -7.0])
        R = rotation_321(0.0, 0.0, math.pi)
        pair = renderer.render(world, pos, R, noise_seed=i)
        from protocols.stereo_frame import StereoFrame

        frame = StereoFrame(i, capture_ns, renderer.camera.intrinsics, pair.left, pair.right)
        recorder.on_frame(frame, 0)
        pose = poses.at(capture_ns).pose
        out = pipeline.process(frame, pose)
        sp = out.setpoint_ned_m
        msg = mavlink.MAVLink_set_position_target_local_ned_message(
            capture_ns // 1_000_000, 1, 1, 1, 2552, *map(float, sp), 0, 0, 0, 0, 0, 0,
            math.remainder(float(out.yaw_rad), math.tau), 0,
        )  # fmt: skip
        if tamper == i:
            msg.x += 1e-3
        msg.pack(mav_us)
        recorder.on_mavlink_out(msg, 0)
        recorder.on_output(frame, pose, out, True, pipeline)
        sent.append(sp.copy())
    recorder.close()
    assert recorder.stats.dropped == 0 and recorder.stats.write_errors == 0
    return sent


def test_recording_replays_bit_for_bit(tmp_path):
    path = tmp_path / "flight.mcap"
    sent = _fly_and_record(path)
    with path.open("rb") as fh:  # a valid MCAP file with our topics (what Foxglove opens)
        reader = make_reader(fh)
        topics = {c.topic for c in reader.get_summary().channels.values()}
    assert {fmt.TOPIC_STEREO, fmt.TOPIC_LEFT, fmt.TOPIC_MAVLINK_IN, fmt.TOPIC_OUTPUT} <= topics
    frames = []
    result = replay(path, on_frame=frames.append)
    assert result.identical, result.summary()
    assert result.frames_recorded == result.frames_replayed == len(sent) == len(frames)
    assert result.setpoints_on_wire == len(sent)
    for got, want in zip(frames, sent, strict=True):
        assert got.setpoint_ned_m.tobytes() == want.tobytes()
    # the flight saw the obstacle: the replay exercises perception, not an empty scene
    assert any(f.output.perception.obstacles for f in frames)
    # and the pose came from the recorded telemetry (float32 yaw): facing south
    np.testing.assert_allclose(
        frames[0].pose.R_ned_from_frd, rotation_321(0.0, 0.0, math.pi), atol=1e-6
    )


def test_replay_reports_a_setpoint_that_differs_on_the_wire(tmp_path):
    path = tmp_path / "tampered.mcap"
    _fly_and_record(path, n_frames=6, tamper=3)
    result = replay(path)
    assert not result.identical
    assert len(result.mismatches) == 1 and "frame 3" in result.mismatches[0]


def test_replay_refuses_files_that_are_not_recordings(tmp_path):
    with pytest.raises(RecordingError, match="cannot open"):
        replay(tmp_path / "none.mcap")
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file at all")
    with pytest.raises(RecordingError, match="not a readable MCAP"):
        replay(junk)
    other = tmp_path / "other.mcap"
    with other.open("wb") as fh:
        w = Writer(fh)
        w.start()
        w.finish()
    with pytest.raises(RecordingError, match="not a companion recording"):
        replay(other)


def test_stereo_avoid_replay_dispatches_on_the_argument(tmp_path, capsys):
    from plant_sim.lockstep.cli import main

    path = tmp_path / "flight.mcap"
    _fly_and_record(path, n_frames=4)
    assert main(["replay", str(path), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["identical"] and summary["frames_replayed"] == 4
    assert main(["replay", str(tmp_path / "missing.mcap")]) == 2
