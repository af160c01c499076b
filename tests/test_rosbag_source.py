"""ROS 2 bags as camera input: a bag written by the test (rosbags, no ROS) drives the companion.

Unit part: image encodings, CameraInfo → intrinsics (closed form), pairing by stamp, clear
errors. Integration part, as ``test_replay_drives_companion.py`` for folders: plant-sim
(autopilot only, hovering at the paper's start), the companion (``--frame-clock host``,
recording with ``--record``) and ``stereo-camera replay BAG --left --right`` of pairs
rendered with an obstacle 3 m ahead; the companion must see the obstacle where it is, start
avoiding it, and its recording must replay bit for bit (pose at capture from the record:
host frame clock).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from _companion_rig import VEHICLE_ID, companion_rig, sees_sphere
from _ros_msgs import OBSTACLE, START_NED_M, TS, CameraInfo, Image, _image, _info
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from companion.camera.rosbag_source import (
    Ros2BagReplay,
    image_to_mono8,
    intrinsics_from_camera_info,
)
from companion.camera.sources import SourceError
from companion.record.replay import replay
from plant_sim.stereo_camera import StereoCameraRenderer
from plant_sim.world import GroundPlane, World
from protocols.camera import CameraModel
from protocols.frames import rotation_321

LEFT, RIGHT = "/stereo/left/image_rect", "/stereo/right/image_rect"


def write_bag(path, n_pairs=20, rate_hz=10.0, storage=StoragePlugin.SQLITE3, skew_ns=0):
    """A ROS 2 bag of rendered pairs (obstacle 3 m ahead) with CameraInfo; returns the model."""
    camera = CameraModel()
    k = camera.intrinsics
    renderer = StereoCameraRenderer(camera)
    R = rotation_321(0.0, 0.0, math.pi)
    world = World(spheres=(OBSTACLE,), ground=GroundPlane(0.0))
    with Writer(path, version=9, storage_plugin=storage) as bag:
        conns = {
            topic: bag.add_connection(topic, msgtype, typestore=TS)
            for topic, msgtype in (
                (LEFT, Image.__msgtype__),
                (RIGHT, Image.__msgtype__),
                ("/stereo/left/camera_info", CameraInfo.__msgtype__),
                ("/stereo/right/camera_info", CameraInfo.__msgtype__),
            )
        }
        t0 = 1_700_000_000_000_000_000
        for i in range(n_pairs):
            stamp = t0 + round(i * 1e9 / rate_hz)
            pair = renderer.render(world, START_NED_M, R, noise_seed=i)
            for topic, msg in (
                ("/stereo/left/camera_info", _info(stamp, k, 0.0)),
                ("/stereo/right/camera_info", _info(stamp, k, -k.fx_px * k.baseline_m)),
                (LEFT, _image(stamp, pair.left)),
                (RIGHT, _image(stamp + skew_ns, pair.right)),
            ):
                bag.write(conns[topic], stamp, TS.serialize_cdr(msg, msg.__msgtype__))
    return camera


# ---- units ------------------------------------------------------------------------------


def test_image_encodings_to_mono8():
    grey = np.arange(12, dtype=np.uint8).reshape(3, 4) * 20
    assert np.array_equal(image_to_mono8(_image(0, grey)), grey)
    rgb = np.stack([grey, grey, grey], axis=-1)
    assert np.array_equal(image_to_mono8(_image(0, rgb, "rgb8")), grey)
    assert np.array_equal(image_to_mono8(_image(0, rgb[..., ::-1], "bgr8")), grey)
    wide = (grey.astype(np.uint16) << 8).astype("<u2")
    assert image_to_mono8(_image(0, wide, "mono16")).dtype == np.uint8
    with pytest.raises(ValueError, match="unsupported image encoding"):
        image_to_mono8(_image(0, grey, "bayer_rggb8"))


def test_camera_info_gives_the_papers_intrinsics():
    k = CameraModel().intrinsics
    got = intrinsics_from_camera_info(_info(0, k, 0.0), _info(0, k, -k.fx_px * k.baseline_m))
    assert got.fx_px == k.fx_px and got.cx_px == k.cx_px and got.cy_px == k.cy_px
    assert got.baseline_m == pytest.approx(0.2, rel=1e-12)
    assert got.focal_baseline_m_px == pytest.approx(71.87, abs=0.005)  # DESIGN.md
    with pytest.raises(ValueError, match="baseline"):
        intrinsics_from_camera_info(_info(0, k, 0.0), _info(0, k, +k.fx_px * 0.2))


def test_ros1_camera_info_gives_the_same_intrinsics():
    """A ROS 1 bag read through rosbags keeps ROS 1's upper-case ``K``/``P`` fields."""
    ros1 = get_typestore(Stores.ROS1_NOETIC).types["sensor_msgs/msg/CameraInfo"]
    k = CameraModel().intrinsics
    infos = []
    for tx in (0.0, -k.fx_px * k.baseline_m):
        ros2 = _info(0, k, tx)
        infos.append(
            ros1(
                header=None, height=ros2.height, width=ros2.width,
                distortion_model=ros2.distortion_model, D=ros2.d, K=ros2.k, R=ros2.r,
                P=ros2.p, binning_x=0, binning_y=0, roi=None,
            )
        )  # fmt: skip
    assert intrinsics_from_camera_info(*infos) == intrinsics_from_camera_info(
        _info(0, k, 0.0), _info(0, k, -k.fx_px * k.baseline_m)
    )


@pytest.mark.parametrize("storage", [StoragePlugin.SQLITE3, StoragePlugin.MCAP])
def test_bag_source_pairs_and_timestamps(tmp_path, storage):
    bag = tmp_path / "bag"
    write_bag(bag, n_pairs=5, storage=storage, skew_ns=300_000)  # right 0.3 ms late
    clock = iter(range(10**12, 10**12 + 100)).__next__
    src = Ros2BagReplay(bag, LEFT, RIGHT, clock=clock)
    src.open()
    try:
        assert src.size_px == (320, 240)
        assert src.intrinsics == CameraModel().intrinsics
        pairs = []
        while (p := src.read()) is not None:
            pairs.append(p)
    finally:
        src.close()
    assert len(pairs) == 5 and src.unpaired == 0
    # recorded spacing (10 Hz) mapped onto the clock at the first read
    assert [p.capture_ns - pairs[0].capture_ns for p in pairs] == [
        i * 100_000_000 for i in range(5)
    ]
    assert pairs[0].capture_ns == 10**12
    assert pairs[0].left.dtype == np.uint8 and not np.array_equal(pairs[0].left, pairs[0].right)


def test_bag_source_errors(tmp_path):
    with pytest.raises(SourceError, match="does not exist"):
        Ros2BagReplay(tmp_path / "none", LEFT, RIGHT).open()
    bag = tmp_path / "bag"
    write_bag(bag, n_pairs=2)
    with pytest.raises(SourceError, match="no topic '/nope'"):
        Ros2BagReplay(bag, "/nope", RIGHT).open()
    with pytest.raises(SourceError, match="not sensor_msgs/msg/Image"):
        Ros2BagReplay(bag, "/stereo/left/camera_info", RIGHT).open()
    skewed = tmp_path / "skewed"
    write_bag(skewed, n_pairs=3, skew_ns=5_000_000)  # 5 ms apart: not pairs
    with pytest.raises(SourceError, match="no left/right pairs"):
        Ros2BagReplay(skewed, LEFT, RIGHT).open()
    with pytest.raises(ValueError, match="same topic"):
        Ros2BagReplay(bag, LEFT, LEFT)


def test_stereo_camera_flags_for_a_bag():
    from companion.camera.__main__ import build_parser, config_from_args

    args = build_parser().parse_args(["replay", "bag", "--left", LEFT, "--right", RIGHT])
    assert config_from_args(args).source.left_topic == LEFT
    with pytest.raises(ValueError, match="both --left"):
        config_from_args(build_parser().parse_args(["replay", "bag", "--left", LEFT]))


# ---- a bag drives the companion ------------------------------------------------------------


def test_ros2_bag_drives_the_companion(tmp_path):
    bag = tmp_path / "bag"
    n_pairs, rate_hz = 60, 10.0
    write_bag(bag, n_pairs=n_pairs, rate_hz=rate_hz, storage=StoragePlugin.MCAP)
    mcap = tmp_path / "companion.mcap"
    with companion_rig(["--record", str(mcap)]) as rig:
        camera = rig.start(
            "stereo-camera",
            "companion.camera",
            ["replay", str(bag), "--left", LEFT, "--right", RIGHT,
             "--zenoh-connect", rig.companion_zenoh, "--vehicle-id", VEHICLE_ID],
        )  # fmt: skip
        ready = camera.wait_line(r"^STEREO_CAMERA READY ", 30)
        assert "source=rosbag:" in ready.string and "size=320x240" in ready.string
        docs = rig.docs
        assert rig.avoiding.wait(n_pairs / rate_hz + 10.0), (
            f"no avoiding status in {len(docs)} docs\n{rig.logs()}"
        )
        # the obstacle model guidance steers on (the map's boundaries, status schema 2)
        first = next(d for d in docs if d["obstacles"])
        why = sees_sphere(first, START_NED_M, OBSTACLE)
        assert why is None, why
        # steering (after 2.5 s of listening): its setpoints are what replay compares
        rig.companion.wait_line(r"^COMPANION EVENT steering ", n_pairs / rate_hz + 10.0)
        rig.companion.stop()
    # host frame clock: the TIMESYNC fit runs on the recorded host times too
    result = replay(mcap)
    assert result.identical, result.summary()
    assert result.frames > 0 and result.setpoints_compared > 0
