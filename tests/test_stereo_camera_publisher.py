"""``python -m companion.camera`` as a process on loopback: replay counts, order, rate and clock,
rectified intrinsics, signals, one-line errors, and replayed pairs driving perception."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import zenoh

from companion.camera.__main__ import main
from companion.camera.calibration import Rectifier, load_calibration
from companion.perception import StereoPerception
from evaluation.sil import ChildProcess, free_port
from plant_sim.stereo_camera import StereoCameraRenderer
from plant_sim.world import Sphere, World
from protocols import stereo_frame
from protocols.camera import CameraModel
from protocols.keys import stereo_key

REPO = Path(__file__).resolve().parents[1]
W, H = 64, 48
K_TINY = np.array([[60.0, 0.0, 31.5], [0.0, 60.0, 23.5], [0.0, 0.0, 1.0]])


def _free_tcp_port() -> int:
    return free_port(socket.SOCK_STREAM)


class CameraProcess(ChildProcess):
    """A ``python -m companion.camera`` child (see :class:`ChildProcess`)."""

    def __init__(self, args: list[str]) -> None:
        super().__init__("stereo-camera", "companion.camera", args)

    def wait_ready(self, timeout_s: float = 20.0) -> str:
        return self.wait_line(r"^STEREO_CAMERA READY ", timeout_s).string

    def wait_exit(self, timeout_s: float = 15.0) -> tuple[int, dict | None]:
        try:
            code = self.proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            raise AssertionError(f"still running after {timeout_s} s\n{self.logs()}") from None
        self._reader.join(timeout=5)
        return code, self.stats("STEREO_CAMERA STATS ")

    def stderr(self) -> str:
        return self.stderr_text()


class Subscriber:
    """Zenoh subscriber on loopback (explicit endpoint, scouting off) collecting raw frames."""

    def __init__(self, endpoint: str, key: str) -> None:
        conf = zenoh.Config()
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
        self._session = zenoh.open(conf)
        self._lock = threading.Lock()
        self._received: list[tuple[int, bytes]] = []
        self._sub = self._session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample) -> None:
        with self._lock:
            self._received.append((time.monotonic_ns(), bytes(sample.payload.to_bytes())))

    def wait_count(self, n: int, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and len(self.received) < n:
            time.sleep(0.01)

    @property
    def received(self) -> list[tuple[int, bytes]]:
        with self._lock:
            return list(self._received)

    def close(self) -> None:
        self._sub.undeclare()
        self._session.close()


def _run_replay(args: list[str], n_expected: int, timeout_s: float = 15.0):
    """Start a replay, subscribe once it is ready, wait for the end: (frames, recv_ns, stats)."""
    endpoint = f"tcp/127.0.0.1:{_free_tcp_port()}"
    proc = CameraProcess(["replay", *args, "--zenoh-listen", endpoint, "--vehicle-id", "camtest"])
    sub = None
    try:
        ready = proc.wait_ready()
        assert f"key={stereo_key('camtest')}" in ready, ready
        sub = Subscriber(endpoint, stereo_key("camtest"))
        sub.wait_count(n_expected, timeout_s)
        code, stats = proc.wait_exit(timeout_s)
        time.sleep(0.05)  # nothing more may arrive
        received = sub.received
        assert code == 0, proc.logs()
        assert stats is not None and stats["stopped_by"] == "end", proc.logs()
        frames = [stereo_frame.decode(payload) for _, payload in received]
        return frames, [t for t, _ in received], stats
    finally:
        if sub is not None:
            sub.close()
        proc.close()


def _pair(i: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(100 + i)
    texture = rng.integers(0, 60, (H, W), dtype=np.uint8)
    return texture + np.uint8(150), texture + np.uint8(20)


def test_replay_publishes_every_pair_in_order_at_the_chosen_rate(tmp_path):
    n = 12
    intrinsics = {
        "width_px": W,
        "height_px": H,
        "fx_px": 60.0,
        "fy_px": 60.0,
        "cx_px": 31.5,
        "cy_px": 23.5,
        "baseline_m": 0.2,
    }
    pairs = []
    for i in range(n):
        left, right = _pair(i)
        cv2.imwrite(str(tmp_path / f"a{i:02d}.png"), left)
        cv2.imwrite(str(tmp_path / f"b{i:02d}.png"), right)
        pairs.append({"left": f"a{i:02d}.png", "right": f"b{i:02d}.png"})
    (tmp_path / "manifest.json").write_text(json.dumps({"pairs": pairs, "intrinsics": intrinsics}))

    t_start = time.monotonic_ns()
    frames, recv_ns, stats = _run_replay([str(tmp_path), "--rate", "20"], n)
    t_end = time.monotonic_ns()

    assert len(frames) == n, f"{len(frames)} frames"
    assert [f.sequence for f in frames] == list(range(n))
    for i, f in enumerate(frames):
        left, right = _pair(i)
        np.testing.assert_array_equal(f.left, left, err_msg=f"pair {i} left")
        np.testing.assert_array_equal(f.right, right, err_msg=f"pair {i} right")
        assert f.encoding is stereo_frame.PixelEncoding.MONO8
        assert f.intrinsics.fx_px == 60.0 and f.intrinsics.baseline_m == 0.2
    capture = [f.capture_ns for f in frames]
    assert np.diff(capture).tolist() == [50_000_000] * (n - 1)  # exactly 1 / 20 Hz
    # one clock: capture times are this host's monotonic clock, and frames leave on time
    assert t_start < capture[0] and capture[-1] < t_end
    lag_ms = (np.array(recv_ns) - np.array(capture)) / 1e6
    assert np.all(lag_ms > 0) and np.all(lag_ms < 250), lag_ms  # generous for loaded CI
    span_s = (recv_ns[-1] - recv_ns[0]) / 1e9
    assert span_s == pytest.approx((n - 1) / 20.0, abs=0.15), span_s
    assert stats["frames"] == n and stats["publish_errors"] == 0


def test_replay_at_recorded_rate_with_rectification(tmp_path):
    """Raw pairs + calibration: recorded stamp gaps kept exactly, rectified intrinsics sent."""
    calib_path = tmp_path / "stereo.yml"
    fs = cv2.FileStorage(str(calib_path), cv2.FILE_STORAGE_WRITE)
    for key, value in (("M1", K_TINY), ("M2", K_TINY), ("R", np.eye(3))):
        fs.write(key, value)
    fs.write("D1", np.zeros((5, 1)))
    fs.write("D2", np.array([[0.01], [0.0], [0.0], [0.0], [0.0]]))
    fs.write("T", np.array([[-100.0], [0.5], [0.0]]))  # millimetres, as often calibrated
    fs.write("units", "mm")
    fs.write("image_width", W)
    fs.write("image_height", H)
    fs.release()
    rec = tmp_path / "rec"
    rec.mkdir()
    stamps = [1_700_000_000_000_000_000 + s for s in (0, 33_000_000, 70_000_000, 99_000_000)]
    for i, stamp in enumerate(stamps):
        left, right = _pair(i)
        cv2.imwrite(str(rec / f"left_{stamp}.png"), left)
        cv2.imwrite(str(rec / f"right_{stamp}.png"), right)

    frames, _, stats = _run_replay([str(rec), "--calibration", str(calib_path)], len(stamps))

    assert len(frames) == len(stamps) == stats["frames"]
    assert np.diff([f.capture_ns for f in frames]).tolist() == np.diff(stamps).tolist()
    rect = Rectifier(load_calibration(calib_path), (W, H))
    assert frames[0].intrinsics == rect.intrinsics
    assert frames[0].intrinsics.baseline_m == pytest.approx(np.hypot(0.1, 0.0005))
    expect_left, expect_right = rect.rectify(*_pair(0))
    np.testing.assert_array_equal(frames[0].left, expect_left)
    np.testing.assert_array_equal(frames[0].right, expect_right)


def _write_tiny_calibration(path: Path, size=(W, H)) -> Path:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in (("K1", K_TINY), ("K2", K_TINY), ("R", np.eye(3))):
        fs.write(key, value)
    fs.write("D1", np.zeros((5, 1)))
    fs.write("D2", np.array([[0.02], [0.0], [0.0], [0.0], [0.0]]))
    fs.write("T", np.array([[-0.1], [0.0], [0.0]]))
    if size is not None:
        fs.write("image_width", size[0])
        fs.write("image_height", size[1])
    fs.release()
    return path


def test_side_by_side_camera_path_rectifies_and_stamps_grab_time(tmp_path):
    """The live path (VideoCapture, split, rectify, DROP publisher, --max-frames) on a
    side-by-side video file standing in for /dev/videoN."""
    calib = _write_tiny_calibration(tmp_path / "c.yml")
    video = str(tmp_path / "sbs.avi")
    writer = cv2.VideoWriter(video, cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (2 * W, H))
    for i in range(6):
        writer.write(cv2.cvtColor(np.hstack(_pair(i)), cv2.COLOR_GRAY2BGR))
    writer.release()
    endpoint = f"tcp/127.0.0.1:{_free_tcp_port()}"
    t_start = time.monotonic_ns()
    proc = CameraProcess(
        [
            *("sbs", video, "--calibration", str(calib), "--max-frames", "3"),
            *("--wait-subscriber", "10", "--zenoh-listen", endpoint, "--vehicle-id", "sbs"),
        ]
    )
    sub = None
    try:
        assert "rectify=calibration" in proc.wait_ready()
        sub = Subscriber(endpoint, stereo_key("sbs"))
        code, stats = proc.wait_exit(15.0)
        assert code == 0 and stats["frames"] == 3, proc.logs()
        assert stats["stopped_by"] == "max_frames"
        sub.wait_count(3, 2.0)
        frames = [stereo_frame.decode(p) for _, p in sub.received]
    finally:
        if sub is not None:
            sub.close()
        proc.close()
    assert [f.sequence for f in frames] == [0, 1, 2]
    assert frames[0].intrinsics == Rectifier(load_calibration(calib), (W, H)).intrinsics
    capture = [f.capture_ns for f in frames]
    assert t_start < capture[0] < capture[1] < capture[2] < time.monotonic_ns()
    for f in frames:  # left half brighter than right half, after rectification too
        assert f.left.mean() > f.right.mean() + 50


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_signal_stops_cleanly_with_stats(tmp_path, sig):
    for i in range(3):
        left, right = _pair(i)
        cv2.imwrite(str(tmp_path / f"left_{i}.png"), left)
        cv2.imwrite(str(tmp_path / f"right_{i}.png"), right)
    proc = CameraProcess(
        [
            *("replay", str(tmp_path), "--rate", "0.5", "--intrinsics", "60,60,31.5,23.5,0.2"),
            *("--wait-subscriber", "0", "--zenoh-listen", f"tcp/127.0.0.1:{_free_tcp_port()}"),
        ]
    )
    try:
        proc.wait_ready()
        time.sleep(0.3)  # first frame out, the second is 2 s away
        proc.proc.send_signal(sig)
        code, stats = proc.wait_exit(5.0)
        assert code == 0, proc.logs()
        assert stats == {**stats, "frames": 1, "stopped_by": "signal"}, proc.logs()
        assert "Traceback" not in proc.stderr()
    finally:
        proc.close()


def test_ready_file_holds_the_readiness_line_while_running(tmp_path):
    """``--ready-file`` (the shared lifecycle): written once READY, removed at exit."""
    frames = tmp_path / "pairs"
    frames.mkdir()
    for i in range(3):
        left, right = _pair(i)
        cv2.imwrite(str(frames / f"left_{i}.png"), left)
        cv2.imwrite(str(frames / f"right_{i}.png"), right)
    ready = tmp_path / "ready"
    proc = CameraProcess(
        [
            *("replay", str(frames), "--rate", "0.5", "--intrinsics", "60,60,31.5,23.5,0.2"),
            *("--wait-subscriber", "0", "--zenoh-listen", f"tcp/127.0.0.1:{_free_tcp_port()}"),
            *("--ready-file", str(ready)),
        ]
    )
    try:
        line = proc.wait_ready()
        assert ready.read_text().strip() == line.strip()
        proc.proc.send_signal(signal.SIGINT)
        code, stats = proc.wait_exit(5.0)
        assert code == 0 and stats["stopped_by"] == "signal", proc.logs()
        assert not ready.exists()
    finally:
        proc.close()


def test_missing_device_is_one_line_without_traceback(tmp_path):
    calib = _write_tiny_calibration(tmp_path / "c.yml")
    proc = subprocess.run(
        [
            *(sys.executable, "-m", "companion.camera", "v4l2", "/dev/video97", "/dev/video98"),
            *("--calibration", str(calib), "--zenoh-listen", f"tcp/127.0.0.1:{_free_tcp_port()}"),
        ],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=20,
        check=False,
    )
    assert proc.returncode == 1, proc.stderr
    assert proc.stderr.strip() == (
        "stereo-camera: camera error: left camera /dev/video97: device does not exist "
        "(is it plugged in?)"
    ), proc.stderr
    assert proc.stdout == ""


def _write_raw(folder: Path, right_size=(W, H)) -> Path:
    folder.mkdir()
    left, right = _pair(0)
    cv2.imwrite(str(folder / "left_1000000000.png"), left)
    cv2.imwrite(str(folder / "right_1000000000.png"), cv2.resize(right, right_size))
    return folder


@pytest.mark.parametrize(
    ("argv", "code", "expect"),
    [
        (
            lambda p: ["replay", str(_write_raw(p / "r")), "--calibration", str(p / "nope.yml")],
            2,
            "configuration error: calibration file {p}/nope.yml does not exist",
        ),
        (
            lambda p: [
                "replay",
                str(_write_raw(p / "r")),
                "--calibration",
                str(p / "r/left_1000000000.png"),
            ],
            2,
            "configuration error: calibration file {p}/r/left_1000000000.png is not OpenCV",
        ),
        (
            lambda p: [
                *("replay", str(_write_raw(p / "r")), "--calibration"),
                str(_write_tiny_calibration(p / "c.yml", size=(320, 240))),
            ],
            2,
            "configuration error: {p}/c.yml: calibrated for 320x240 but the images are 64x48",
        ),
        (
            lambda p: ["replay", str(p)],
            1,
            "camera error: no image pairs in {p}",
        ),
        (
            lambda p: [
                "replay",
                str(_write_raw(p / "r", (W // 2, H))),
                "--intrinsics",
                "1,1,1,1,1",
            ],
            1,
            "camera error: size mismatch between eyes",
        ),
        (
            lambda p: ["replay", str(_write_raw(p / "r"))],
            2,
            "configuration error: replay:{p}/r",
        ),
        (
            lambda p: ["v4l2", "0", "1"],
            2,
            "configuration error: cameras need --calibration FILE",
        ),
        (
            lambda p: ["sbs", "/dev/video97", "--intrinsics", "60,60,31.5,23.5,0.2"],
            1,
            "camera error: side-by-side camera /dev/video97: device does not exist",
        ),
    ],
    ids=[
        "missing_calibration",
        "bad_calibration",
        "calibration_size_mismatch",
        "empty_folder",
        "size_mismatch",
        "no_intrinsics",
        "camera_without_calibration",
        "missing_sbs_device",
    ],
)
def test_bad_inputs_give_one_clear_line(tmp_path, capsys, argv, code, expect):
    assert main(argv(tmp_path)) == code
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("stereo-camera: " + expect.format(p=tmp_path)), lines[0]
    assert "STEREO_CAMERA READY" not in out


def test_replayed_rendered_pairs_drive_perception(tmp_path):
    """Pairs rendered by the SIL camera, saved as PNG + manifest, replayed over Zenoh: the
    companion's perception finds the paper's obstacle in the frames it receives."""
    camera = CameraModel()
    sphere = Sphere((10.0, 0.0, -7.0), 1.5)  # the paper's obstacle
    world = World(spheres=(sphere,))
    renderer = StereoCameraRenderer(camera)
    poses = [np.array([10.0 - 1.5 - surface_m, 0.0, -7.0]) for surface_m in (3.2, 3.0, 2.8)]
    pairs = []
    for i, pos in enumerate(poses):
        out = renderer.render(world, pos, np.eye(3), noise_seed=i)
        cv2.imwrite(str(tmp_path / f"left_{i}.png"), out.left)
        cv2.imwrite(str(tmp_path / f"right_{i}.png"), out.right)
        pairs.append(
            {"left": f"left_{i}.png", "right": f"right_{i}.png", "stamp_ns": i * 33_333_333}
        )
    k = camera.intrinsics
    manifest = {"pairs": pairs, "intrinsics": {f: getattr(k, f) for f in k.__dataclass_fields__}}
    (tmp_path / "manifest.json").write_text(json.dumps(manifest))

    frames, _, _ = _run_replay([str(tmp_path)], len(poses))

    assert [f.sequence for f in frames] == [0, 1, 2]
    perception = StereoPerception()
    for frame, pos in zip(frames, poses, strict=True):
        assert frame.intrinsics == k
        result = perception.process(frame, pos, np.eye(3))
        assert result.obstacles, f"no obstacle in frame {frame.sequence}"
        nearest = result.obstacles[0]
        gap_m = np.linalg.norm(nearest.center_ned_m - np.asarray(sphere.center_ned_m))
        assert gap_m + sphere.radius_m <= nearest.radius_m, (frame.sequence, gap_m)  # encloses it
        assert nearest.nearest_range_m == pytest.approx(pos_to_surface(pos, sphere), abs=0.3)


def pos_to_surface(pos: np.ndarray, sphere: Sphere) -> float:
    """Range from the left eye (at body y = -b/2) to the sphere's surface [m]."""
    eye = pos + np.array([0.0, -0.1, 0.0])
    return float(np.linalg.norm(np.asarray(sphere.center_ned_m) - eye) - sphere.radius_m)
