"""Depth-camera sources of ``stereo-camera`` (issue 35): ROS bags with depth image topics and
RealSense recordings, through the real libraries (rosbags, pyrealsense2) without a camera.

Units: depth image encodings (16UC1, 32FC1 with REP 117's infinities), CameraInfo →
intrinsics, the CLI's flags. Recordings: a ROS 2 bag with a depth topic written by
rosbags; a RealSense ROS 1 ``.bag`` as SDKs before 2.59 recorded them, written by rosbags
in librealsense's layout (``_realsense_ros1.py``); the ``.db3`` pyrealsense2 2.59 records
(its software device under its own recorder). Both RealSense formats are read back
through pyrealsense2's own playback frame for frame, and the ``.bag`` through rosbags
without the SDK. ``test_depth_camera_companion.py`` replays them into a running companion.

Conformance: every public class of ours with ``read() -> RawDepth`` is discovered
(``_contracts.implementations``) and run against the ``DepthFrameSource`` contract; one
without a case in ``CASES`` fails.
"""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest
from _contracts import check_coverage, implementations
from _realsense_recorder import record_with_sdk
from _realsense_ros1 import write_realsense_ros1_bag
from _ros_msgs import OBSTACLE, START_NED_M, TS, Image, _image, _info
from rosbags.rosbag2 import StoragePlugin, Writer

from companion.camera.__main__ import build_parser, config_from_args
from companion.camera.depth_sources import (
    DepthFrameSource,
    Ros2DepthBagReplay,
    depth_from_image_msg,
    intrinsics_from_depth_info,
)
from companion.camera.sources import SourceError
from plant_sim.depth_camera import DepthNoiseParams, depth16_from_truth
from plant_sim.stereo_camera import StereoCameraRenderer
from plant_sim.world import GroundPlane, World
from protocols.camera import CameraModel
from protocols.frames import rotation_321
from protocols.stereo_frame import PixelEncoding

CAMERA = CameraModel()
K = CAMERA.intrinsics
DEPTH, DEPTH_INFO, PICTURE = "/camera/depth/image_rect_raw", "/camera/depth/camera_info", "/ir"


def _views(n: int):
    """``n`` (depth16 plane, left picture) of the obstacle 3 m ahead, RealSense-like noise."""
    renderer = StereoCameraRenderer(CAMERA)
    R = rotation_321(0.0, 0.0, math.pi)
    world = World(spheres=(OBSTACLE,), ground=GroundPlane(0.0))
    for i in range(n):
        out = renderer.render(world, START_NED_M, R, noise_seed=i)
        yield depth16_from_truth(out.depth_left_m, K, DepthNoiseParams(), i), out.left


# ---- units ------------------------------------------------------------------------------


@pytest.mark.parametrize("bigendian", [False, True])
def test_16uc1_is_millimetres(bigendian):
    mm = np.array([[0, 1000], [2500, 65535]], dtype=np.uint16)
    msg = _image(0, mm.astype(">u2" if bigendian else "<u2"), "16UC1")
    msg.is_bigendian = int(bigendian)
    plane, encoding, scale = depth_from_image_msg(msg)
    np.testing.assert_array_equal(plane, mm)
    assert (encoding, scale) == (PixelEncoding.DEPTH16, 0.001)


def test_32fc1_is_metres_and_infinities_are_no_data():
    m = np.array([[1.5, np.nan, np.inf], [-np.inf, -1.0, 0.0]], dtype=np.float32)
    plane, encoding, scale = depth_from_image_msg(_image(0, m, "32FC1"))
    assert (encoding, scale) == (PixelEncoding.DEPTH32F, 1.0)
    assert plane[0, 0] == 1.5 and plane[1, 2] == 0.0
    assert np.isnan(plane[[0, 0, 1, 1], [1, 2, 0, 1]]).all()  # never +inf: never free


def test_unsupported_and_short_depth_images_raise():
    with pytest.raises(ValueError, match="unsupported depth encoding"):
        depth_from_image_msg(_image(0, np.zeros((2, 2), np.uint8), "mono8"))
    msg = _image(0, np.zeros((2, 2), np.uint16), "16UC1")
    msg.data = msg.data[:-1]
    with pytest.raises(ValueError, match="bytes"):
        depth_from_image_msg(msg)


def test_depth_camera_info_gives_the_papers_intrinsics_with_the_stated_baseline():
    k = intrinsics_from_depth_info(_info(0, K, 0.0), 0.2)
    assert k == K
    with pytest.raises(ValueError, match="baseline"):
        intrinsics_from_depth_info(_info(0, K, 0.0), 0.0)


def test_cli_flags_for_depth_sources():
    parse = build_parser().parse_args
    cfg = config_from_args(parse(["replay", "bag", "--depth", DEPTH, "--baseline", "0.05"]))
    assert (cfg.source.depth_topic, cfg.source.baseline_m) == (DEPTH, 0.05)
    assert cfg.wait_subscriber_s == math.inf
    with pytest.raises(ValueError, match="--baseline"):
        config_from_args(parse(["replay", "bag", "--depth", DEPTH]))
    with pytest.raises(ValueError, match="no --calibration"):
        config_from_args(parse(["realsense", "--bag", "x.bag", "--calibration", "stereo.yml"]))
    with pytest.raises(ValueError, match="need --depth"):
        config_from_args(parse(["replay", "folder", "--image", PICTURE]))
    live = config_from_args(parse(["realsense", "--size", "848x480", "--fps", "30"]))
    assert live.source.size_px == (848, 480) and live.wait_subscriber_s == 0.0


# ---- a ROS 2 bag with a depth topic --------------------------------------------------------


def write_depth_bag(path, n=30, rate_hz=10.0, with_picture=True):
    """A ROS 2 bag (MCAP) of depth16 images with their CameraInfo and the left picture."""
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as bag:
        conns = {
            DEPTH: bag.add_connection(DEPTH, Image.__msgtype__, typestore=TS),
            DEPTH_INFO: bag.add_connection(DEPTH_INFO, "sensor_msgs/msg/CameraInfo", typestore=TS),
        }
        if with_picture:
            conns[PICTURE] = bag.add_connection(PICTURE, Image.__msgtype__, typestore=TS)
        t0 = 1_700_000_000_000_000_000
        for i, (plane, left) in enumerate(_views(n)):
            stamp = t0 + round(i * 1e9 / rate_hz)
            msgs = [(DEPTH_INFO, _info(stamp, K, 0.0)), (DEPTH, _image(stamp, plane, "16UC1"))]
            if with_picture:
                msgs.append((PICTURE, _image(stamp, left)))
            for topic, msg in msgs:
                bag.write(conns[topic], stamp, TS.serialize_cdr(msg, msg.__msgtype__))


def test_depth_bag_source_reads_frames_pictures_and_stamps(tmp_path):
    write_depth_bag(tmp_path / "bag", n=5)
    now = iter(range(10**9, 10**10, 10**6))
    source = Ros2DepthBagReplay(
        tmp_path / "bag", DEPTH, 0.2, image_topic=PICTURE, clock=lambda: next(now)
    )
    source.open()
    assert source.intrinsics == K and source.size_px == (320, 240)
    items = [source.read() for _ in range(6)]
    source.close()
    assert items[-1] is None
    frames = items[:-1]
    assert all(f.encoding is PixelEncoding.DEPTH16 and f.depth_scale_m == 0.001 for f in frames)
    assert all(f.left is not None and f.left.shape == (240, 320) for f in frames)
    np.testing.assert_array_equal(np.diff([f.capture_ns for f in frames]), 100_000_000)
    expected = next(_views(1))[0]
    np.testing.assert_array_equal(frames[0].depth, expected)


def test_depth_bag_errors(tmp_path):
    write_depth_bag(tmp_path / "bag", n=2, with_picture=False)
    with pytest.raises(SourceError, match="no topic '/nope'"):
        Ros2DepthBagReplay(tmp_path / "bag", "/nope", 0.2).open()
    with pytest.raises(SourceError, match="no topic '/ir'"):
        Ros2DepthBagReplay(tmp_path / "bag", DEPTH, 0.2, image_topic=PICTURE).open()
    with pytest.raises(SourceError, match="does not exist"):
        Ros2DepthBagReplay(tmp_path / "missing", DEPTH, 0.2).open()


# ---- a RealSense recording made without a camera --------------------------------------------


def write_realsense_recording(path, n=60, rate_hz=10.0):
    """Record ``n`` depth (Z16, 1 mm) + infrared 1 (Y8) frames of the obstacle scene with
    pyrealsense2's software device under its recorder; the baseline is in the recording as
    the infrared 1 → 2 extrinsics and the ``stereo_baseline`` option."""
    rs = pytest.importorskip("pyrealsense2")
    record_with_sdk(rs, path, K, _views(n), rate_hz=rate_hz)


def write_realsense_bag(path, n=60, rate_hz=10.0, **kwargs):
    """A RealSense ROS 1 ``.bag`` (older SDKs' format) of ``n`` frames of the obstacle scene."""
    write_realsense_ros1_bag(path, K, _views(n), rate_hz=rate_hz, **kwargs)


@pytest.mark.parametrize("suffix", [".db3", ".bag"])
def test_realsense_recording_is_read_back_by_pyrealsense2(tmp_path, suffix):
    """pyrealsense2's playback gives back each recorded plane bit for bit, the intrinsics
    (float32 in the file), depth scale and baseline, and the device stamps 100 ms apart."""
    pytest.importorskip("pyrealsense2")
    from companion.camera.realsense_source import RealSenseSource

    path = tmp_path / f"rec{suffix}"
    if suffix == ".db3":  # pyrealsense2 2.59 records ROS 2 (sqlite3) bags
        write_realsense_recording(path, n=5)
    else:
        write_realsense_bag(path, n=5)
    now = iter(range(10**9, 10**10, 10**6))
    source = RealSenseSource(path, clock=lambda: next(now))
    source.open()
    assert source.intrinsics.width_px == 320 and source.intrinsics.baseline_m == pytest.approx(0.2)
    assert source.intrinsics.fx_px == pytest.approx(K.fx_px, rel=1e-6)
    assert source.intrinsics.cy_px == pytest.approx(K.cy_px, rel=1e-6)
    assert source.depth_scale_m == pytest.approx(0.001, rel=1e-6)
    frames = []
    while (item := source.read()) is not None:
        frames.append(item)
    source.close()
    assert len(frames) == 5
    for frame, (plane, left) in zip(frames, _views(5), strict=True):
        np.testing.assert_array_equal(frame.depth, plane)
        np.testing.assert_array_equal(frame.left, left)
        assert frame.depth_scale_m == pytest.approx(0.001, rel=1e-6)
    np.testing.assert_array_equal(np.diff([f.capture_ns for f in frames]), 100_000_000)


@pytest.mark.parametrize("image_units_m", [0.0005, None])
def test_ros1_bag_depth_units_come_from_the_frame_else_the_option(tmp_path, image_units_m):
    """SDKs since 2.49 append each depth image's units after its data (their Header's
    third field, "version", says "1"); older bags have none and playback takes the "Depth
    Units" option. The frame's units, not the sensor's, scale what is published."""
    pytest.importorskip("pyrealsense2")
    from companion.camera.realsense_source import RealSenseSource

    path = tmp_path / "rec.bag"
    write_realsense_bag(path, n=2, depth_scale_m=0.001, image_depth_units_m=image_units_m)
    source = RealSenseSource(path, clock=iter(range(10**9, 10**10, 10**6)).__next__)
    source.open()
    frame = source.read()
    source.close()
    assert source.depth_scale_m == pytest.approx(0.001, rel=1e-6)
    expected = 0.001 if image_units_m is None else image_units_m
    assert frame.depth_scale_m == pytest.approx(expected, rel=1e-6)


def test_realsense_bag_errors_name_the_file_and_the_reason(tmp_path):
    """A ``.bag`` that is not a RealSense recording is refused with librealsense's reason."""
    pytest.importorskip("pyrealsense2")
    from rosbags.rosbag1 import Writer as Ros1Writer
    from rosbags.typesys import Stores, get_typestore

    from companion.camera.realsense_source import RealSenseSource

    ts = get_typestore(Stores.ROS1_NOETIC)
    path = tmp_path / "not_realsense.bag"
    with Ros1Writer(path) as bag:
        conn = bag.add_connection("/chatter", "std_msgs/msg/String", typestore=ts)
        msg = ts.types["std_msgs/msg/String"](data="hello")
        bag.write(conn, 1_000_000, ts.serialize_ros1(msg, msg.__msgtype__))
    with pytest.raises(SourceError, match=r"not_realsense\.bag.*file_version"):
        RealSenseSource(path).open()


# ---- the DepthFrameSource contract, for every implementation -------------------------------


def _ros2_depth_case(tmp_path):
    write_depth_bag(tmp_path / "bag", n=5)
    return Ros2DepthBagReplay(tmp_path / "bag", DEPTH, 0.2, image_topic=PICTURE)


def _realsense_bag_case(tmp_path):
    from companion.camera.realsense_source import RealSenseSource

    pytest.importorskip("pyrealsense2")
    write_realsense_bag(tmp_path / "rec.bag", n=5)
    return RealSenseSource(tmp_path / "rec.bag")


RS_DEPTH = "/device_0/sensor_0/Depth_0/image/data"
RS_DEPTH_INFO = "/device_0/sensor_0/Depth_0/info/camera_info"
RS_PICTURE = "/device_0/sensor_0/Infrared_1/image/data"


def _realsense_bag_through_rosbags_case(tmp_path):
    write_realsense_bag(tmp_path / "rec.bag", n=5)
    return Ros2DepthBagReplay(
        tmp_path / "rec.bag", RS_DEPTH, 0.2, info_topic=RS_DEPTH_INFO, image_topic=RS_PICTURE
    )


CASES = {
    "companion.camera.depth_sources.Ros2DepthBagReplay": [
        _ros2_depth_case,
        _realsense_bag_through_rosbags_case,
    ],
    "companion.camera.realsense_source.RealSenseSource": [_realsense_bag_case],
}
DISCOVERED = implementations("read", "RawDepth")


def test_every_depth_frame_source_has_a_conformance_case():
    check_coverage(DISCOVERED, CASES, "depth frame sources (read() -> RawDepth)", 2)


@pytest.mark.parametrize(
    ("name", "make"),
    [(name, make) for name in DISCOVERED for make in CASES.get(name, [None])],
    ids=lambda x: x.rsplit(".", 1)[1] if isinstance(x, str) else getattr(x, "__name__", "none"),
)
def test_depth_frame_source_contract(tmp_path, name, make):
    """Sizes and intrinsics only after open(), each of the 5 recorded frames once (depth
    planes as recorded, the left picture beside them), capture times strictly increasing,
    then None for good; close() twice is fine."""
    if make is None:
        pytest.fail(f"{name} implements read() -> RawDepth but has no case in CASES")
    source = make(tmp_path)
    assert f"{type(source).__module__}.{type(source).__qualname__}" == name
    assert isinstance(source, DepthFrameSource)
    assert isinstance(source.description, str) and source.description
    assert source.size_px is None and source.intrinsics is None
    source.open()
    try:
        assert source.size_px == (K.width_px, K.height_px)
        assert source.intrinsics.baseline_m == pytest.approx(K.baseline_m)
        frames = []
        while (item := source.read()) is not None:
            frames.append(item)
            assert len(frames) <= 5, "a frame delivered twice"
        assert source.read() is None and source.read() is None, "stays at the end"
    finally:
        source.close()
    source.close()
    assert len(frames) == 5
    for frame, (plane, left) in zip(frames, _views(5), strict=True):
        assert frame.encoding is PixelEncoding.DEPTH16 and frame.depth_scale_m == pytest.approx(
            0.001, rel=1e-6
        )
        np.testing.assert_array_equal(frame.depth, plane)
        np.testing.assert_array_equal(frame.left, left)
    stamps = [f.capture_ns for f in frames]
    assert all(isinstance(t, int) for t in stamps)
    assert all(b > a for a, b in itertools.pairwise(stamps)), stamps


@pytest.mark.parametrize(
    ("image_units_m", "option_units_m", "expected_m"),
    [(0.0005, 0.001, 0.0005), (None, 0.00025, 0.00025)],
    ids=["units-in-frames", "units-option-only"],
)
def test_realsense_bag_replays_without_pyrealsense2(
    tmp_path, image_units_m, option_units_m, expected_m
):
    """A RealSense ``.bag`` through ``stereo-camera replay --depth`` (rosbags, no SDK): the
    4 bytes of depth units SDK 2.49+ appends after each image are read, not refused; a bag
    without them takes the recording's "Depth Units" option; intrinsics from the depth
    stream's CameraInfo (ROS 1's upper-case ``K``), stamps the device's, 100 ms apart."""
    path = tmp_path / "rec.bag"
    write_realsense_bag(path, n=3, depth_scale_m=option_units_m, image_depth_units_m=image_units_m)
    now = iter(range(10**9, 10**10, 10**6))
    source = Ros2DepthBagReplay(
        path, RS_DEPTH, 0.2, info_topic=RS_DEPTH_INFO, image_topic=RS_PICTURE,
        clock=lambda: next(now),
    )  # fmt: skip
    source.open()
    frames = [source.read() for _ in range(3)]
    assert source.read() is None
    source.close()
    assert source.intrinsics == K
    for frame, (plane, left) in zip(frames, _views(3), strict=True):
        assert frame.depth_scale_m == pytest.approx(expected_m, rel=1e-6)
        np.testing.assert_array_equal(frame.depth, plane)
        np.testing.assert_array_equal(frame.left, left)
    np.testing.assert_array_equal(np.diff([f.capture_ns for f in frames]), 100_000_000)


def test_a_malformed_image_in_a_ros1_bag_is_a_clear_error(tmp_path):
    """Extra bytes after an image are read as RealSense's depth units only where the header
    says so (frame_id "1"); anywhere else the bag is refused naming the topic, not crashed."""
    from rosbags.rosbag1 import Writer as Ros1Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    T = ts.types
    path = tmp_path / "bad.bag"
    plane = next(_views(1))[0]
    stamp = T["builtin_interfaces/msg/Time"](sec=1, nanosec=0)
    image = T["sensor_msgs/msg/Image"](
        header=T["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=""),
        height=K.height_px, width=K.width_px, encoding="16UC1", is_bigendian=0,
        step=2 * K.width_px, data=plane.view(np.uint8).reshape(-1),
    )  # fmt: skip
    info = T["sensor_msgs/msg/CameraInfo"](
        header=image.header, height=K.height_px, width=K.width_px, distortion_model="",
        D=np.zeros(5), K=np.array([K.fx_px, 0, K.cx_px, 0, K.fy_px, K.cy_px, 0, 0, 1.0]),
        R=np.zeros(9), P=np.zeros(12), binning_x=0, binning_y=0,
        roi=T["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        ),
    )  # fmt: skip
    with Ros1Writer(path) as bag:
        for topic, msg, tail in ((DEPTH_INFO, info, b""), (DEPTH, image, b"\0\0\0\0")):
            conn = bag.add_connection(topic, msg.__msgtype__, typestore=ts)
            bag.write(conn, 1_000_000, bytes(ts.serialize_ros1(msg, msg.__msgtype__)) + tail)
    source = Ros2DepthBagReplay(path, DEPTH, 0.05, info_topic=DEPTH_INFO)
    with pytest.raises(SourceError, match=r"bad\.bag: /camera/depth/image_rect_raw"):
        source.open()


def _sdk_fixture():
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "make_realsense_sdk_bag", Path(__file__).parent / "data" / "make_realsense_sdk_bag.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("path", ["pyrealsense2", "rosbags"])
def test_a_bag_recorded_by_the_sdk_itself_plays_through_both_paths(path):
    """``tests/data/realsense_sdk2.56.5.bag``, written by librealsense 2.56.5's own recorder
    (ROS 1, how every existing recording was made): pyrealsense2 2.59's playback
    (``stereo-camera realsense --bag``) and rosbags (``stereo-camera replay --depth``) give
    back its planes, pictures, intrinsics, 1 mm units and 100 ms device steps."""
    fixture = _sdk_fixture()
    k = fixture.K
    if path == "pyrealsense2":
        from companion.camera.realsense_source import RealSenseSource

        pytest.importorskip("pyrealsense2")
        source = RealSenseSource(fixture.BAG)
    else:
        source = Ros2DepthBagReplay(
            fixture.BAG, RS_DEPTH, k.baseline_m, info_topic=RS_DEPTH_INFO, image_topic=RS_PICTURE
        )
    source.open()
    frames = []
    while (item := source.read()) is not None:
        frames.append(item)
    source.close()
    got = source.intrinsics
    assert (got.width_px, got.height_px) == (k.width_px, k.height_px)
    assert (got.fx_px, got.fy_px, got.cx_px, got.cy_px) == (k.fx_px, k.fy_px, k.cx_px, k.cy_px)
    assert got.baseline_m == pytest.approx(k.baseline_m, rel=1e-6)  # float32 in the file
    assert len(frames) == fixture.N_FRAMES
    for frame, (plane, picture) in zip(frames, fixture.frames(), strict=True):
        assert frame.encoding is PixelEncoding.DEPTH16
        assert frame.depth_scale_m == pytest.approx(0.001, rel=1e-6)
        np.testing.assert_array_equal(frame.depth, plane)
        np.testing.assert_array_equal(frame.left, picture)
    np.testing.assert_array_equal(np.diff([f.capture_ns for f in frames]), 100_000_000)


def test_live_device_time_is_mapped_by_the_smallest_offset():
    """Live: capture = device time + min(arrival - device time) over the window: never
    later than the arrival, exact once a frame came with the minimum transport delay, and
    following a drifting device clock (no device needed: the mapping alone)."""
    from companion.camera.realsense_source import _OFFSET_WINDOW, RealSenseSource

    source = RealSenseSource()
    rng = np.random.default_rng(5)
    clock_offset_ns = 5_000_000_000  # host monotonic = device time + 5 s
    min_delay_ns = 2_000_000
    errors = []
    for i in range(3 * _OFFSET_WINDOW):
        device_ns = i * 33_333_333
        drift_ns = i * 1_000  # the device clock runs 30 ppm slow
        truth_ns = device_ns + clock_offset_ns + drift_ns
        arrival_ns = truth_ns + min_delay_ns + int(rng.exponential(3_000_000))
        capture_ns = source._capture_ns(device_ns, arrival_ns)
        assert capture_ns <= arrival_ns
        errors.append(capture_ns - truth_ns)
    late = np.array(errors[_OFFSET_WINDOW:])
    # after one window: within the minimum delay plus the drift over one window
    assert np.all(late >= min_delay_ns - _OFFSET_WINDOW * 1_000), late.min()
    assert np.all(late <= min_delay_ns + 200_000), late.max()
