"""Frame sources: the StereoSource contract for every implementation, replay layouts and
timing, and the clear errors for missing devices, size mismatches and bad folders.

The implementations are discovered (``_contracts.implementations``: every public class of
ours with ``read() -> RawPair``), and ``test_every_stereo_source_has_a_conformance_case``
fails for one that has no case here; each runs without hardware (the camera classes read
video files through the same VideoCapture path they use for /dev/videoN, a ROS 2 bag is
written by rosbags)."""

from __future__ import annotations

import itertools
import json
from dataclasses import dataclass

import cv2
import numpy as np
import pytest
from _contracts import check_coverage, implementations
from rosbags.rosbag2 import Writer
from rosbags.typesys import Stores, get_typestore

from companion.camera.rosbag_source import Ros2BagReplay
from companion.camera.sources import (
    FolderReplay,
    MemorySource,
    SideBySideCamera,
    SourceError,
    StereoSource,
    V4L2PairCamera,
    to_mono8,
)

W, H = 64, 48
N = 6
BASE_NS = 1_700_000_000_000_000_000  # a realistic epoch stamp in a file name
RECORDED_STEPS_NS = [0, 40_000_000, 70_000_000, 130_000_000, 160_000_000, 200_000_000]


def _pair(i: int) -> tuple[np.ndarray, np.ndarray]:
    """Pair i: textured, left brighter than right (so swapped eyes are caught)."""
    rng = np.random.default_rng(i)
    texture = rng.integers(0, 40, (H, W), dtype=np.uint8)
    return texture + np.uint8(180), texture + np.uint8(40)


def _fake_clock(start_ns: int = 5_000_000_000, step_ns: int = 1_000):
    counter = itertools.count()
    return lambda: start_ns + step_ns * next(counter)


def _write_names(folder, rgb: bool = False):
    folder.mkdir(exist_ok=True)
    for i in range(N):
        left, right = _pair(i)
        if rgb:  # colour files are converted to MONO8
            left, right = (cv2.cvtColor(x, cv2.COLOR_GRAY2BGR) for x in (left, right))
        cv2.imwrite(str(folder / f"left_{BASE_NS + RECORDED_STEPS_NS[i]}.png"), left)
        cv2.imwrite(str(folder / f"right_{BASE_NS + RECORDED_STEPS_NS[i]}.png"), right)
    return folder


def _write_manifest(folder, stamps: bool = True):
    (folder / "l").mkdir(parents=True)
    (folder / "r").mkdir()
    pairs = []
    for i in range(N):
        left, right = _pair(i)
        cv2.imwrite(str(folder / "l" / f"{i:04d}.png"), left)
        cv2.imwrite(str(folder / "r" / f"{i:04d}.png"), right)
        item = {"left": f"l/{i:04d}.png", "right": f"r/{i:04d}.png"}
        if stamps:
            item["stamp_ns"] = RECORDED_STEPS_NS[i]
        pairs.append(item)
    (folder / "manifest.json").write_text(json.dumps({"pairs": pairs}))
    return folder


def _write_video(path, frames) -> str:
    h, w = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (w, h))
    assert writer.isOpened()
    for frame in frames:
        writer.write(cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR))
    writer.release()
    return str(path)


@dataclass(frozen=True)
class Case:
    source: StereoSource
    lossless: bool  # pixels must match exactly (else: up to MJPG compression)
    first: int = 0  # index of the first pair delivered (cameras use one to learn the size)


# Every implementation that can run without hardware; the camera classes read video files
# through the same VideoCapture path they use for /dev/videoN.
def _memory(tmp_path):
    return Case(MemorySource([_pair(i) for i in range(N)], rate_hz=30.0), True)


def _replay_names(tmp_path):
    return Case(FolderReplay(_write_names(tmp_path / "rec", rgb=True)), True)


def _replay_manifest(tmp_path):
    return Case(FolderReplay(_write_manifest(tmp_path / "rec"), rate_hz=15.0), True)


def _v4l2_pair_on_files(tmp_path):
    left = _write_video(tmp_path / "l.avi", [_pair(i)[0] for i in range(N)])
    right = _write_video(tmp_path / "r.avi", [_pair(i)[1] for i in range(N)])
    return Case(V4L2PairCamera(left, right), False, first=1)


def _side_by_side_on_file(tmp_path):
    frames = [np.hstack(_pair(i)) for i in range(N)]
    return Case(SideBySideCamera(_write_video(tmp_path / "sbs.avi", frames)), False, first=1)


def _ros2_bag(tmp_path):
    ts = get_typestore(Stores.ROS2_HUMBLE)
    Image, Header = ts.types["sensor_msgs/msg/Image"], ts.types["std_msgs/msg/Header"]
    Time = ts.types["builtin_interfaces/msg/Time"]
    with Writer(tmp_path / "bag", version=9) as bag:
        conns = [bag.add_connection(f"/{eye}", Image.__msgtype__, typestore=ts) for eye in "lr"]
        for i in range(N):
            stamp = BASE_NS + RECORDED_STEPS_NS[i]
            header = Header(stamp=Time(sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id="")
            for conn, image in zip(conns, _pair(i), strict=True):
                msg = Image(
                    header=header,
                    height=H,
                    width=W,
                    encoding="mono8",
                    is_bigendian=0,
                    step=W,
                    data=image.reshape(-1),
                )
                bag.write(conn, stamp, ts.serialize_cdr(msg, msg.__msgtype__))
    return Case(Ros2BagReplay(tmp_path / "bag", "/l", "/r"), True)


# Every public implementation, by its qualified name: how to make one that runs here.
CASES = {
    "companion.camera.sources.MemorySource": [_memory],
    "companion.camera.sources.FolderReplay": [_replay_names, _replay_manifest],
    "companion.camera.sources.V4L2PairCamera": [_v4l2_pair_on_files],
    "companion.camera.sources.SideBySideCamera": [_side_by_side_on_file],
    "companion.camera.rosbag_source.Ros2BagReplay": [_ros2_bag],
}
# (private bases such as ``_LiveCamera`` are not sources of their own)
DISCOVERED = [n for n in implementations("read", "RawPair") if n.rsplit(".", 1)[1][0] != "_"]


def test_every_stereo_source_has_a_conformance_case():
    check_coverage(DISCOVERED, CASES, "stereo sources (read() -> RawPair)", 5)


@pytest.fixture(
    params=[(name, make) for name in DISCOVERED for make in CASES.get(name, [None])],
    ids=lambda p: f"{p[0].rsplit('.', 1)[1]}-{getattr(p[1], '__name__', 'no case')}",
)
def case(request, tmp_path) -> Case:
    name, make = request.param
    if make is None:
        pytest.fail(f"{name} implements read() -> RawPair but has no case in CASES")
    made = make(tmp_path)
    assert f"{type(made.source).__module__}.{type(made.source).__qualname__}" == name
    return made


def test_source_contract(case):
    source = case.source
    assert isinstance(source, StereoSource)
    assert isinstance(source.description, str) and source.description
    assert source.size_px is None  # only known after open()
    source.open()
    try:
        assert source.size_px == (W, H)
        pairs = []
        for _ in range(N + 1):
            pair = source.read()
            if pair is None:
                break
            pairs.append(pair)
        assert len(pairs) == N - case.first, "every pair exactly once"
        assert source.read() is None and source.read() is None, "stays at the end"
        stamps = [p.capture_ns for p in pairs]
        assert all(isinstance(s, int) for s in stamps)
        assert all(b > a for a, b in itertools.pairwise(stamps)), stamps
        for i, pair in enumerate(pairs, start=case.first):
            for name, image in (("left", pair.left), ("right", pair.right)):
                assert image.dtype == np.uint8 and image.shape == (H, W), (i, name)
            expect_left, expect_right = _pair(i)
            if case.lossless:
                np.testing.assert_array_equal(pair.left, expect_left, err_msg=f"pair {i}")
                np.testing.assert_array_equal(pair.right, expect_right, err_msg=f"pair {i}")
            else:  # MJPG: same picture up to compression
                assert abs(pair.left.mean() - expect_left.mean()) < 3.0, i
                assert abs(pair.right.mean() - expect_right.mean()) < 3.0, i
    finally:
        source.close()
    source.close()  # idempotent


def test_replay_maps_recorded_stamps_onto_monotonic_start(tmp_path):
    clock = _fake_clock(start_ns=42_000_000_000)
    replay = FolderReplay(_write_names(tmp_path / "rec"), clock=clock)
    replay.open()
    stamps = [replay.read().capture_ns for _ in range(N)]
    assert stamps == [42_000_000_000 + s for s in RECORDED_STEPS_NS]


def test_replay_at_chosen_rate(tmp_path):
    replay = FolderReplay(_write_names(tmp_path / "rec"), rate_hz=20.0, clock=_fake_clock(7))
    replay.open()
    stamps = [replay.read().capture_ns for _ in range(N)]
    assert np.diff(stamps).tolist() == [50_000_000] * (N - 1)


@pytest.mark.parametrize("layout", ["left", "cam0/data"])
def test_replay_subfolder_layouts(tmp_path, layout):
    right_dir = {"left": "right", "cam0/data": "cam1/data"}[layout]
    for sub in (layout, right_dir):
        (tmp_path / sub).mkdir(parents=True)
    for i in range(3):
        left, right = _pair(i)
        cv2.imwrite(str(tmp_path / layout / f"{BASE_NS + i * 33_000_000}.png"), left)
        cv2.imwrite(str(tmp_path / right_dir / f"{BASE_NS + i * 33_000_000}.png"), right)
    replay = FolderReplay(tmp_path, clock=_fake_clock(0, 0))
    replay.open()
    assert len(replay) == 3
    assert [replay.read().capture_ns for _ in range(3)] == [0, 33_000_000, 66_000_000]


def test_to_mono8_formats():
    gray = np.arange(12, dtype=np.uint8).reshape(3, 4)
    assert to_mono8(gray) is not None and to_mono8(gray).tolist() == gray.tolist()
    bgr = cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)
    np.testing.assert_array_equal(to_mono8(bgr), gray)
    np.testing.assert_array_equal(to_mono8(gray.astype(np.uint16) << 8), gray)
    with pytest.raises(ValueError, match="unsupported pixel type"):
        to_mono8(gray.astype(np.float32))


# ------------------------------------------------------------------------- errors


def _open_error(source) -> str:
    with pytest.raises(SourceError) as info:
        source.open()
    source.close()
    message = str(info.value)
    assert "\n" not in message
    return message


@pytest.mark.parametrize("device", ["/dev/video97", "97"])
def test_missing_v4l2_device(device):
    message = _open_error(V4L2PairCamera(device, "/dev/video98"))
    assert "left camera /dev/video97: device does not exist" in message
    message = _open_error(SideBySideCamera(device))
    assert "/dev/video97: device does not exist" in message


def test_device_that_is_not_a_camera():
    message = _open_error(SideBySideCamera("/dev/null"))
    assert "/dev/null: cannot open" in message


def test_size_mismatch_between_cameras(tmp_path):
    left = _write_video(tmp_path / "l.avi", [_pair(0)[0]] * 2)
    right = _write_video(tmp_path / "r.avi", [cv2.resize(_pair(0)[1], (2 * W, 2 * H))] * 2)
    message = _open_error(V4L2PairCamera(left, right))
    assert "size mismatch between eyes" in message and "64x48" in message
    assert "128x96" in message


def test_empty_and_missing_folder(tmp_path):
    assert "no image pairs in" in _open_error(FolderReplay(tmp_path))
    assert "does not exist" in _open_error(FolderReplay(tmp_path / "nope"))


def test_unpaired_unreadable_and_mismatched_images(tmp_path):
    rec = _write_names(tmp_path / "a")
    next(rec.glob("right_*.png")).unlink()
    assert "has no partner image" in _open_error(FolderReplay(rec))

    rec = _write_names(tmp_path / "b")
    sorted(rec.glob("left_*.png"))[0].write_bytes(b"not a png")
    assert "cannot read image" in _open_error(FolderReplay(rec))

    rec = _write_names(tmp_path / "c")
    victim = sorted(rec.glob("right_*.png"))[0]
    cv2.imwrite(str(victim), np.zeros((H // 2, W // 2), np.uint8))
    assert "size mismatch between eyes" in _open_error(FolderReplay(rec))

    rec = _write_names(tmp_path / "d")  # a bad image later on fails at read()
    sorted(rec.glob("left_*.png"))[-1].write_bytes(b"")
    replay = FolderReplay(rec)
    replay.open()
    for _ in range(N - 1):
        replay.read()
    with pytest.raises(SourceError, match="cannot read image"):
        replay.read()


def test_replay_needs_a_rate_without_timestamps(tmp_path):
    rec = _write_manifest(tmp_path / "rec", stamps=False)
    assert "choose a rate" in _open_error(FolderReplay(rec))
    FolderReplay(rec, rate_hz=10.0).open()
    idx = tmp_path / "idx"  # KITTI-like frame indices are not nanoseconds
    idx.mkdir()
    for i in range(3):
        for eye in ("left", "right"):
            cv2.imwrite(str(idx / f"{eye}_{i:06d}.png"), _pair(i)[0])
    assert "look like frame indices" in _open_error(FolderReplay(idx))


def test_bad_manifest(tmp_path):
    rec = _write_manifest(tmp_path / "rec")
    doc = json.loads((rec / "manifest.json").read_text())
    (rec / "manifest.json").write_text(json.dumps({**doc, "fps": 3}))
    assert "unknown key(s) ['fps']" in _open_error(FolderReplay(rec))
    (rec / "manifest.json").write_text("{not json")
    assert "cannot read manifest" in _open_error(FolderReplay(rec))
