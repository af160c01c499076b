"""Recording and viewing, in process: geometry closed forms, observers, record → replay.

The record → replay round trip here steps a :class:`CompanionCore` against a scripted
ArduCopter with rendered frames of the paper's obstacle, its steps shown to the recorder
as the service shows them; the networked SIL round trip is in ``test_view_sil.py``.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import logging
import math

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.config import CompanionConfig, build_parser, config_from_args
from companion.core import (
    CompanionCore,
    FrameProcessed,
    FrameReceived,
    MavlinkReceived,
    SendMavlink,
    SendSetpoint,
    Tick,
)
from companion.guidance import GuidanceConfig
from companion.observe import CompanionObserver, Observers
from companion.perception import PerceptionConfig
from companion.record import format as fmt
from companion.record.recorder import McapRecorder
from companion.record.replay import RecordingError, replay
from companion.viz.options import ViewOptionError, observers_from_args
from companion.viz.rerun_log import RerunObserver, RerunTarget
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
from protocols.signing import SigningKey
from protocols.stereo_frame import StereoFrame

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
    rec, view = observers_from_args(tmp_path / "x.mcap", "serve:8000")
    assert isinstance(rec, McapRecorder) and not rec.wants_pipeline
    assert isinstance(view, RerunObserver) and view.wants_pipeline
    assert Observers([rec, view]).wants_pipeline and not Observers([rec]).wants_pipeline
    args = build_parser().parse_args(["--record", str(tmp_path / "x.mcap"), "--rerun", "serve"])
    assert args.record == tmp_path / "x.mcap" and args.rerun == "serve"
    config_from_args(args)  # the flags are not config: the config still builds


def test_companion_refuses_bad_view_flags(tmp_path, capsys):
    from companion.__main__ import main

    assert main(["--record", str(tmp_path / "x.txt")]) == 2
    assert "--record takes FILE.mcap" in capsys.readouterr().err
    assert main(["--rerun", "x.png"]) == 2
    assert "--rerun takes FILE.rrd" in capsys.readouterr().err


def test_without_the_view_extra_the_flags_name_it(tmp_path, capsys, monkeypatch):
    """rerun-sdk and mcap are an optional extra: a missing one is a clear error, exit 2."""
    real = importlib.util.find_spec
    missing = {"rerun", "mcap", "rosbags"}
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name in missing else real(name, *a)
    )
    from companion.__main__ import main
    from evaluation.cli import main as stereo_avoid

    assert main(["--rerun", str(tmp_path / "x.rrd")]) == 2
    err = capsys.readouterr().err
    assert "--rerun needs rerun-sdk" in err and "pip install 'stereo-avoid[view]'" in err
    assert main(["--record", str(tmp_path / "x.mcap")]) == 2
    assert "--record needs mcap" in capsys.readouterr().err
    assert stereo_avoid(["paper", "--rerun", str(tmp_path / "x.rrd")]) == 2
    assert "stereo-avoid[view]" in capsys.readouterr().err
    assert stereo_avoid(["replay", str(tmp_path / "x.mcap")]) == 2
    assert "stereo-avoid[view]" in capsys.readouterr().err
    from companion.camera.__main__ import build_parser as camera_parser
    from companion.camera.__main__ import config_from_args as camera_config

    bag_args = camera_parser().parse_args(["replay", "bag", "--left", "/l", "--right", "/r"])
    with pytest.raises(ViewOptionError, match=r"needs rosbags.*stereo-avoid\[view\]"):
        camera_config(bag_args)


class _Boom(CompanionObserver):
    def on_step(self, event, outputs):
        raise RuntimeError("bug")


class _Count(CompanionObserver):
    def __init__(self):
        self.steps = []

    def on_step(self, event, outputs):
        self.steps.append((event, list(outputs)))


def test_observers_fan_out_and_contain_failures(caplog):
    assert not Observers()  # the service's guard: no observers, no calls
    count = _Count()
    obs = Observers([_Boom(), count])
    assert obs and len(obs) == 2
    with caplog.at_level(logging.ERROR, logger="companion.observe"):
        for i in range(3):
            obs.on_step(Tick(i), [])
    assert [e.now_ns for e, _ in count.steps] == [0, 1, 2]  # the failing one starves no one
    assert len([r for r in caplog.records if "_Boom.on_step failed" in r.message]) == 1


def test_config_round_trip_through_a_recording():
    config = CompanionConfig(
        waypoints_ned_m=((5.0, 1.0, -3.0), (0.0, 0.0, -7.0)),
        perception=PerceptionConfig(threshold_m=5.0, safety_margin_m=0.4),
        guidance=GuidanceConfig.from_dict({}),
    )
    secret = "correct horse battery staple"
    config = dataclasses.replace(
        config,
        link=dataclasses.replace(
            config.link, signing_key=SigningKey.from_text(secret), px4_prestream_s=2.0
        ),
    )
    text = json.dumps(fmt.config_to_dict(config))
    assert "signing" not in text and SigningKey.from_text(secret).secret.hex() not in text
    back = fmt.config_from_recorded(json.loads(text), signing=True)
    for name in ("waypoints_ned_m", "perception", "guidance", "known_space", "envelope"):
        assert getattr(back, name) == getattr(config, name), name
    assert dataclasses.replace(back.link, signing_key=None) == dataclasses.replace(
        config.link, signing_key=None
    )
    assert back.link.signing_key is not None  # a placeholder: the core asks only "is one set"
    assert fmt.config_from_recorded(json.loads(text), signing=False).link.signing_key is None


def test_mavlink_frame_fields_leave_out_what_the_link_adds():
    msg = mavlink.MAVLink_set_position_target_local_ned_message(
        1234, 1, 1, 1, 2552, 1.5, -2.0, -7.0, 0, 0, 0, 0, 0, 0, 0.25, 0
    )
    plain = bytes(msg.pack(mavlink.MAVLink(None, srcSystem=1, srcComponent=196)))
    signer = mavlink.MAVLink(None, srcSystem=1, srcComponent=196)
    signer.seq = 77
    signer.signing.secret_key = bytes(range(32))
    signer.signing.sign_outgoing = True
    signed = bytes(msg.pack(signer))
    assert signed != plain and len(signed) == len(plain) + 13  # sequence, signature
    fields = fmt.mavlink_frame_fields(plain)
    assert fields == fmt.mavlink_frame_fields(signed)
    assert fields[:3] == (mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED, 1, 196)
    v1 = mavlink.MAVLink(None, srcSystem=3, srcComponent=4)
    v1.WIRE_PROTOCOL_VERSION = "1.0"
    hb = mavlink.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3)
    assert fmt.mavlink_frame_fields(bytes(hb.pack(v1, force_mavlink1=True)))[:3] == (0, 3, 4)
    for bad in (b"", b"\x00" * 20, plain[:-5]):
        with pytest.raises(ValueError):
            fmt.mavlink_frame_fields(bad)


# ---- record → replay, in process -----------------------------------------------------------

GUIDED = 4
SMALL = CameraModel(width_px=160, height_px=120)  # fast matcher; same field of view


class _Flight:
    """A :class:`CompanionCore` and a scripted ArduCopter in GUIDED, flying south at 1 m/s
    from (17, 0, −7) toward the paper's obstacle, with frames rendered at the true pose.

    Every 10 ms of host time a tick, every 20 ms telemetry, every 1/30 s a frame, every
    second a heartbeat; commands are ACKed and TIMESYNC answered. As in the service, the
    outputs of a step are "sent" (packed by a link encoder with its own sequence numbers)
    before the observers see the step. ``tamper``: the n-th setpoint's x is moved 1 mm
    on the wire.
    """

    def __init__(self, observers: Observers, tamper: int | None = None) -> None:
        self.config = CompanionConfig()
        self.core = CompanionCore(self.config, 0x5EED, report_pipeline=observers.wants_pipeline)
        self.observers = observers
        self.tamper = tamper
        self.ap = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.link = mavlink.MAVLink(None, srcSystem=1, srcComponent=196)
        self.renderer = StereoCameraRenderer(SMALL)
        self.world = paper_world()
        self.now_ns = 1_000_000_000
        self.boot_offset_ns = 400_000_000
        self.setpoints_sent = 0
        self.frames_processed = 0
        self._seq = 0

    @property
    def boot_ms(self) -> int:
        return (self.now_ns - self.boot_offset_ns) // 1_000_000

    def pos_ned_m(self, boot_ms: int) -> tuple[float, float, float]:
        return (17.0 - 1.0 * (boot_ms * 1e-3 - 0.6), 0.0, -7.0)

    def step(self, event) -> None:
        outputs = self.core.step(event)
        for o in outputs:
            if isinstance(o, SendSetpoint):
                self.setpoints_sent += 1
                if self.setpoints_sent == self.tamper:
                    o.message.x += 1e-3
            if isinstance(o, SendMavlink | SendSetpoint):
                o.message.pack(self.link)
        self.observers.on_step(event, outputs)
        for o in outputs:
            if isinstance(o, SendMavlink):
                self._answer(o.message)

    def receive(self, msg) -> None:
        got = self.ap.decode(bytearray(msg.pack(self.ap)))
        self.step(MavlinkReceived(got, self.now_ns))

    def _answer(self, msg) -> None:
        if msg.get_type() == "COMMAND_LONG":
            self.receive(mavlink.MAVLink_command_ack_message(msg.command, 0))
        elif msg.get_type() == "TIMESYNC" and msg.tc1 == 0:
            autopilot_ns = self.now_ns - self.boot_offset_ns
            self.receive(mavlink.MAVLink_timesync_message(autopilot_ns, msg.ts1))

    def run(self, seconds: float) -> None:
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        for tick in range(1, round(seconds / 0.01) + 1):
            self.now_ns += 10_000_000
            if tick % 100 == 1:
                self.receive(
                    mavlink.MAVLink_heartbeat_message(
                        mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                        base, GUIDED, mavlink.MAV_STATE_ACTIVE, 3,
                    )
                )  # fmt: skip
            if tick % 2 == 0:
                p = self.pos_ned_m(self.boot_ms)
                self.receive(
                    mavlink.MAVLink_local_position_ned_message(self.boot_ms, *p, -1.0, 0, 0)
                )
                self.receive(mavlink.MAVLink_attitude_message(self.boot_ms, 0, 0, math.pi, 0, 0, 0))
            if tick % 3 == 0:
                self.step(FrameReceived(self._frame(), self.now_ns, self.now_ns))
            self.step(Tick(self.now_ns))
        self.frames_processed = self.core.counters.frames_processed

    def _frame(self) -> StereoFrame:
        capture_ns = self.boot_ms * 1_000_000
        pos = np.array(self.pos_ned_m(self.boot_ms))
        pair = self.renderer.render(
            self.world, pos, rotation_321(0.0, 0.0, math.pi), noise_seed=self._seq
        )
        frame = StereoFrame(self._seq, capture_ns, SMALL.intrinsics, pair.left, pair.right)
        self._seq += 1
        return frame


def _record(path, seconds=4.0, tamper=None) -> _Flight:
    recorder = McapRecorder(path)
    flight = _Flight(Observers([recorder]), tamper)
    recorder.on_start(flight.config, flight.core.instance_id)
    flight.run(seconds)
    recorder.close()
    assert recorder.stats.dropped == 0 and recorder.stats.write_errors == 0
    assert recorder.stats.frames == round(seconds * 100) // 3
    return flight


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    path = tmp_path_factory.mktemp("rec") / "flight.mcap"
    return path, _record(path)


def test_recording_replays_bit_for_bit(flight):
    path, flown = flight
    with path.open("rb") as fh:  # a valid MCAP file with our topics (what Foxglove opens)
        reader = make_reader(fh)
        summary = reader.get_summary()
        topics = {c.topic: c.message_encoding for c in summary.channels.values()}
        counts = {
            summary.channels[cid].topic: n
            for cid, n in summary.statistics.channel_message_counts.items()
        }
    assert topics[fmt.TOPIC_LEFT] == "json" and topics[fmt.TOPIC_MAVLINK_OUT] == "mavlink2"
    assert counts[fmt.TOPIC_TICK] == 400 and counts[fmt.TOPIC_STEREO] == 133
    assert 0 < counts[fmt.TOPIC_LEFT] <= 41  # the Foxglove preview: at most 10 Hz
    done: list[FrameProcessed] = []
    result = replay(path, on_frame=done.append)
    assert result.identical, result.summary()
    assert result.setpoints_compared == flown.setpoints_sent > 10
    assert result.mavlink_compared == counts[fmt.TOPIC_MAVLINK_OUT]
    assert result.inputs == sum(counts[t] for t in (fmt.TOPIC_TICK, fmt.TOPIC_MAVLINK_IN,
                                                    fmt.TOPIC_STEREO))  # fmt: skip
    # the replayed core processed the same frames; the flight saw the obstacle and avoided
    assert len(done) == flown.frames_processed > 60
    assert any(d.step.output.perception.obstacles for d in done)
    assert any(d.step.output.guidance.avoidance_flag for d in done)
    assert all(d.setpoint_sent for d in done[-10:])


def test_the_core_reports_processed_frames_only_for_viewers():
    quiet = _Flight(Observers([_Count()]))
    quiet.run(0.7)
    steps = quiet.observers._observers[0].steps
    assert not any(isinstance(o, FrameProcessed) for _, outs in steps for o in outs)

    class Viewer(_Count):
        wants_pipeline = True

    viewer = Viewer()
    shown = _Flight(Observers([viewer]))
    shown.run(0.7)
    done = [o for _, outs in viewer.steps for o in outs if isinstance(o, FrameProcessed)]
    assert len(done) == shown.frames_processed > 0
    assert all(d.frame.sequence == i for i, d in enumerate(done))
    assert all(d.known_space is shown.core.mission.pipeline.known_space for d in done)


def test_replay_reports_a_setpoint_that_differs_on_the_wire(tmp_path):
    path = tmp_path / "tampered.mcap"
    _record(path, seconds=3.2, tamper=3)
    result = replay(path)
    assert not result.identical
    assert len(result.mismatches) == 1, result.mismatches
    assert (
        f"message {mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED}" in (result.mismatches[0])
    )


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
    old = tmp_path / "old.mcap"
    with old.open("wb") as fh:
        w = Writer(fh)
        w.start()
        w.add_metadata(fmt.METADATA, {"format": "1"})
        w.finish()
    with pytest.raises(RecordingError, match="format '1'"):
        replay(old)


def test_stereo_avoid_replay_dispatches_on_the_argument(flight, tmp_path, capsys):
    from evaluation.cli import main

    path, flown = flight
    assert main(["replay", str(path), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["identical"] and summary["setpoints_compared"] == flown.setpoints_sent
    rrd = tmp_path / "replay.rrd"
    assert main(["replay", str(path), "--rerun", str(rrd)]) == 0
    assert "IDENTICAL" in capsys.readouterr().out
    assert _rows(_rrd_chunks(rrd), "/world/vehicle") == flown.frames_processed
    assert main(["replay", str(tmp_path / "missing.mcap")]) == 2
    assert main(["replay", "not-a-seed"]) == 2
    assert "neither a seed" in capsys.readouterr().err


# ---- Rerun: what the companion's view and the lockstep view log ---------------------------


def _rrd_chunks(path):
    from rerun.chunk import RrdReader

    return RrdReader(path).store().stream().to_chunks()


def _rows(chunks, entity: str) -> int:
    return sum(c.num_rows for c in chunks if c.entity_path == entity and not c.is_static)


def test_companion_rerun_view_logs_the_scene_per_frame(tmp_path):
    """The core's FrameProcessed outputs, drawn by the observer ``companion --rerun``
    uses: every processed frame logged, skipped (the view lags) or decimated (≤ 10 Hz)."""
    rrd = tmp_path / "view.rrd"
    view = RerunObserver(RerunTarget.parse(str(rrd)))
    flight = _Flight(Observers([view]))
    view.on_start(flight.config, flight.core.instance_id)
    flight.run(3.6)
    view.close()
    chunks = _rrd_chunks(rrd)
    entities = {c.entity_path for c in chunks}
    for entity in (
        "/world/vehicle",
        "/world/vehicle/camera/image",
        "/world/vehicle/camera/depth",
        "/world/vehicle/camera/classes",
        "/world/obstacle_points",
        "/world/boundaries",
        "/world/tracks",
        "/world/cones",
        "/world/aiming_point",
        "/world/setpoint",
        "/world/goal",
        "/world/known_space",
        "/status/avoidance_flag",
        "/status/mode",
    ):
        assert entity in entities, (entity, sorted(entities))
    frames = flight.frames_processed
    assert view.logged + view.skipped + view.decimated == frames > 60
    assert 0 < view.logged <= frames // 3 + 1  # 30 Hz camera, ≤ 10 Hz view
    assert _rows(chunks, "/world/vehicle") == _rows(chunks, "/world/setpoint") == view.logged
    assert _rows(chunks, "/world/vehicle/camera/depth") == view.logged


def test_lockstep_rerun_view_adds_ground_truth(tmp_path):
    from evaluation.harness import RunConfig, run_scene
    from evaluation.scenes import paper_scene
    from evaluation.view import LockstepView

    rrd = tmp_path / "paper.rrd"
    cfg = RunConfig(max_time_s=0.3)
    view = LockstepView(str(rrd), paper_scene(), cfg)
    result = run_scene(paper_scene(), cfg, on_step=view.on_step)
    view.close()
    chunks = _rrd_chunks(rrd)
    assert "/world/truth/spheres" in {c.entity_path for c in chunks}
    assert _rows(chunks, "/world/vehicle") == result.verdict.frames
    assert _rows(chunks, "/world/vehicle/camera/depth") == result.verdict.frames
