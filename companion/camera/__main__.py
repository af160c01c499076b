"""``python -m companion.camera`` / ``stereo-camera``: publish real or recorded stereo frames.

Reads pairs from two V4L2 cameras (``v4l2``), one side-by-side UVC camera (``sbs``) or a
folder of recorded pairs (``replay``), rectifies them with an OpenCV stereo calibration
(:mod:`companion.camera.calibration`) and publishes them as
:mod:`protocols.stereo_frame` MONO8 frames on ``stereo_avoid/<vehicle_id>/stereo``: a
drop-in replacement for plant-sim's synthetic camera. Examples::

    stereo-camera v4l2 0 2 --calibration stereo.yml --size 640x480 --fps 30
    stereo-camera sbs /dev/video0 --calibration intrinsics.yml --calibration extrinsics.yml \\
        --size 640x480 --output-size 320x240
    stereo-camera replay recording/ --rate 10 --zenoh-connect tcp/192.168.1.5:7447
    stereo-camera replay flight_bag/ --left /stereo/left/image_rect --right /stereo/right/image_rect

Once the source delivers and the Zenoh publisher is declared it prints one line on stdout::

    STEREO_CAMERA READY key=stereo_avoid/sim1/stereo source=replay:rec size=320x240
        rectify=none zenoh=listen:tcp/127.0.0.1:7447

(also written to ``--ready-file``, removed at exit: the same lifecycle as plant-sim and the
companion, :func:`protocols.process.run_until_signalled`) and at exit (end of a replay,
``--max-frames``, SIGINT or SIGTERM) ``STEREO_CAMERA STATS {json}``. Capture times are
``time.monotonic_ns()`` at grab for cameras and the recorded timestamps mapped onto the
monotonic clock at replay start for replays (:mod:`companion.camera.sources`). Exit
status: 0 on a clean stop, 1 on a camera, file or transport error, 2 on a bad
configuration or calibration; errors are one line on stderr.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import re
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from companion.camera.config import (
    CameraConfig,
    SourceConfig,
    SourceKind,
    depth_camera_config,
)
from protocols.process import (
    DEFAULT_ENDPOINT,
    add_zenoh_arguments,
    default_listen,
    run_until_signalled,
)
from protocols.threads import configure_threads
from protocols.zenoh_session import ZenohSettings, zenoh_config

if TYPE_CHECKING:  # numpy & co. load inside main(), after OPENBLAS_NUM_THREADS is set
    from protocols.camera import StereoIntrinsics

__all__ = [
    "CameraConfig",
    "CameraService",
    "SourceConfig",
    "SourceKind",
    "build_parser",
    "config_from_args",
    "main",
    "make_source",
]

_log = logging.getLogger("companion.camera")
_PROG = "stereo-camera"
_FLUSH_S = 0.2  # after the last frame of a finite source, before closing the session
_RUST_LOCATION = re.compile(r" at /\S+\.rs:\d+\.?")  # zenoh appends its source location


# --------------------------------------------------------------------------- command line


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size must be WIDTHxHEIGHT, got {text!r}") from None
    if not (1 <= w <= 8192 and 1 <= h <= 8192):
        raise argparse.ArgumentTypeError(f"size must be within 1..8192 each, got {text!r}")
    return w, h


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not value > 0 or math.isnan(value):
        raise argparse.ArgumentTypeError(f"must be > 0, got {text!r}")
    return value


def _seconds(text: str) -> float:
    if text.lower() in ("inf", "forever"):
        return math.inf
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seconds or 'inf', got {text!r}") from None
    if not value >= 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text!r}")
    return value


def _common_options() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(add_help=False)
    g = p.add_argument_group("calibration and rectification")
    g.add_argument(
        "--calibration",
        action="append",
        default=[],
        type=Path,
        metavar="FILE",
        help="OpenCV stereo calibration (YAML/XML/JSON with K1 D1 K2 D2 R T [image size]); "
        "repeatable, e.g. intrinsics.yml + extrinsics.yml",
    )
    g.add_argument(
        "--calibration-units",
        choices=["m", "cm", "mm"],
        help="unit of T in the calibration (default: the file's 'units' entry, else m)",
    )
    g.add_argument(
        "--intrinsics",
        metavar="FX,FY,CX,CY,BASELINE_M",
        help="the input is already rectified: its intrinsics (no remap)",
    )
    g.add_argument(
        "--alpha",
        type=float,
        default=0.0,
        help="stereoRectify free scaling: 0 valid pixels only (default), 1 all pixels",
    )
    g.add_argument("--output-size", type=_size, metavar="WxH", help="rectified size per eye")
    z = p.add_argument_group("zenoh")
    add_zenoh_arguments(
        z,
        listen_default=f"default {DEFAULT_ENDPOINT} when none is given",
        connect_help="router or companion",
    )
    z.add_argument("--vehicle-id", default="sim1", help="key chunk (default sim1)")
    o = p.add_argument_group("run")
    o.add_argument(
        "--wait-subscriber",
        type=_seconds,
        metavar="S",
        help="wait up to S seconds ('inf') for a subscriber before the first frame "
        "(default: inf for replay, 0 for cameras)",
    )
    o.add_argument("--max-frames", type=int, metavar="N", help="stop after N frames")
    o.add_argument("--log-level", default="INFO", choices=["DEBUG", "INFO", "WARNING", "ERROR"])
    o.add_argument(
        "--ready-file",
        type=Path,
        help="also write the readiness line to this file (removed at exit): a healthcheck",
    )
    return p


def build_parser() -> argparse.ArgumentParser:
    common = _common_options()
    p = argparse.ArgumentParser(
        prog=_PROG,
        description="Publish rectified stereo frames (MONO8) over Zenoh from cameras or a "
        "recording.",
    )
    sub = p.add_subparsers(dest="kind", required=True, metavar="{v4l2,sbs,replay,realsense}")
    cam = argparse.ArgumentParser(add_help=False)
    cam.add_argument("--size", type=_size, metavar="WxH", help="requested size of each eye")
    cam.add_argument("--fps", type=_positive, help="requested camera rate [Hz]")
    cam.add_argument("--fourcc", help="requested pixel format, e.g. MJPG or YUYV")
    v = sub.add_parser(
        "v4l2", parents=[cam, common], help="two cameras (index or /dev/videoN each)"
    )
    v.add_argument("left", help="left (reference) camera: index or /dev/videoN")
    v.add_argument("right", help="right camera: index or /dev/videoN")
    s = sub.add_parser("sbs", parents=[cam, common], help="one side-by-side stereo camera")
    s.add_argument("device", help="index or /dev/videoN")
    r = sub.add_parser("replay", parents=[common], help="folder of recorded pairs, or a ROS 2 bag")
    r.add_argument(
        "folder",
        type=Path,
        help="recording (manifest.json or left_*/right_* files), or with --left/--right a "
        "ROS 2 bag (folder, .db3 or .mcap)",
    )
    r.add_argument("--rate", type=_positive, metavar="HZ", help="replay rate (default: recorded)")
    r.add_argument("--left", metavar="TOPIC", help="ROS 2 bag: left sensor_msgs/Image topic")
    r.add_argument("--right", metavar="TOPIC", help="ROS 2 bag: right sensor_msgs/Image topic")
    r.add_argument(
        "--left-info", metavar="TOPIC", help="ROS 2 bag: left CameraInfo (default: beside image)"
    )
    r.add_argument(
        "--right-info", metavar="TOPIC", help="ROS 2 bag: right CameraInfo (default: beside)"
    )
    r.add_argument("--depth", metavar="TOPIC", help="ROS bag: depth image (16UC1 mm / 32FC1 m)")
    r.add_argument(
        "--depth-info", metavar="TOPIC", help="ROS bag: depth CameraInfo (default: beside)"
    )
    r.add_argument("--image", metavar="TOPIC", help="ROS bag: the depth camera's left picture")
    r.add_argument(
        "--baseline", type=_positive, metavar="M", help="depth camera's stereo baseline [m]"
    )
    rs = sub.add_parser(
        "realsense", parents=[common], help="Intel RealSense depth camera or recording"
    )
    rs.add_argument("--bag", type=Path, metavar="FILE", help="play back a RealSense recording")
    rs.add_argument("--size", type=_size, metavar="WxH", help="depth size (default 640x480)")
    rs.add_argument("--fps", type=_positive, help="camera rate [Hz] (default 30)")
    rs.add_argument("--rate", type=_positive, metavar="HZ", help="recording: replay rate")
    rs.add_argument(
        "--baseline", type=_positive, metavar="M", help="override the device's baseline [m]"
    )
    rs.add_argument("--no-image", action="store_true", help="depth only, no infrared picture")
    return p


def _parse_intrinsics(text: str) -> StereoIntrinsics:
    from protocols.camera import StereoIntrinsics

    try:
        fx, fy, cx, cy, baseline = (float(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"--intrinsics must be FX,FY,CX,CY,BASELINE_M, got {text!r}") from None
    # width/height are placeholders, replaced by the source's size once it is open
    return StereoIntrinsics(1, 1, fx, fy, cx, cy, baseline)


def config_from_args(args: argparse.Namespace) -> CameraConfig:
    """The one place CLI flags become a :class:`CameraConfig` (raises ValueError if invalid)."""
    from protocols.keys import validate_vehicle_id

    kind = SourceKind(args.kind)
    if kind is SourceKind.REALSENSE or getattr(args, "depth", None) is not None:
        return depth_camera_config(kind, args)
    if (
        getattr(args, "image", None)
        or getattr(args, "depth_info", None)
        or getattr(args, "baseline", None)
    ):
        raise ValueError("--image/--depth-info/--baseline need --depth TOPIC (a depth bag)")
    if kind is SourceKind.REPLAY:
        if (args.left is None) != (args.right is None):
            raise ValueError("a ROS 2 bag needs both --left TOPIC and --right TOPIC")
        if args.left is None and (args.left_info or args.right_info):
            raise ValueError("--left-info/--right-info need --left and --right (a ROS 2 bag)")
        if args.left is not None:
            from companion.viz.options import require_extra

            require_extra("a ROS 2 bag (--left/--right)", "rosbags", "rosbags")
        source = SourceConfig(
            kind,
            folder=args.folder,
            rate_hz=args.rate,
            left_topic=args.left,
            right_topic=args.right,
            left_info_topic=args.left_info,
            right_info_topic=args.right_info,
        )
    else:
        devices = (args.left, args.right) if kind is SourceKind.V4L2_PAIR else (args.device,)
        if args.fourcc is not None and len(args.fourcc) != 4:
            raise ValueError(f"--fourcc must be 4 characters, got {args.fourcc!r}")
        source = SourceConfig(
            kind, devices=devices, size_px=args.size, fps=args.fps, fourcc=args.fourcc
        )
    if args.calibration and args.intrinsics:
        raise ValueError("give --calibration (raw input) or --intrinsics (rectified), not both")
    if kind is not SourceKind.REPLAY and not (args.calibration or args.intrinsics):
        raise ValueError("cameras need --calibration FILE (or --intrinsics if pre-rectified)")
    if args.output_size is not None and not args.calibration:
        raise ValueError("--output-size needs --calibration (it rescales the rectification)")
    intrinsics = _parse_intrinsics(args.intrinsics) if args.intrinsics else None
    listen = default_listen(args.zenoh_listen, args.zenoh_connect, args.zenoh_config)
    if args.zenoh_config is not None and not args.zenoh_config.is_file():
        raise ValueError(f"--zenoh-config {args.zenoh_config} does not exist")
    wait = args.wait_subscriber
    if wait is None:
        wait = math.inf if kind is SourceKind.REPLAY else 0.0
    return CameraConfig(
        source=source,
        vehicle_id=validate_vehicle_id(args.vehicle_id),
        zenoh=ZenohSettings(
            listen=listen, connect=tuple(args.zenoh_connect), config_file=args.zenoh_config
        ),
        calibration_files=tuple(args.calibration),
        calibration_units=args.calibration_units,
        intrinsics=intrinsics,
        alpha=args.alpha,
        output_size_px=args.output_size,
        wait_subscriber_s=wait,
        max_frames=args.max_frames,
    )


# --------------------------------------------------------------------------- running


def make_source(config: SourceConfig):
    """The :class:`~companion.camera.sources.StereoSource` (or, for a depth camera, the
    :class:`~companion.camera.depth_sources.DepthFrameSource`) for ``config`` (not yet open)."""
    from companion.camera import sources

    if config.kind is SourceKind.V4L2_PAIR:
        left, right = config.devices
        return sources.V4L2PairCamera(left, right, config.size_px, config.fps, config.fourcc)
    if config.kind is SourceKind.SIDE_BY_SIDE:
        return sources.SideBySideCamera(
            config.devices[0], config.size_px, config.fps, config.fourcc
        )
    if config.kind is SourceKind.REALSENSE:
        from companion.camera.realsense_source import RealSenseSource

        return RealSenseSource(
            config.folder,
            size_px=config.size_px,
            fps=config.fps,
            baseline_m=config.baseline_m,
            with_image=config.with_image,
            rate_hz=config.rate_hz,
        )
    if config.depth_topic is not None:
        from companion.camera.depth_sources import Ros2DepthBagReplay

        return Ros2DepthBagReplay(
            config.folder,
            config.depth_topic,
            config.baseline_m,
            info_topic=config.depth_info_topic,
            image_topic=config.image_topic,
            rate_hz=config.rate_hz,
        )
    if config.left_topic is not None and config.right_topic is not None:
        from companion.camera.rosbag_source import Ros2BagReplay

        return Ros2BagReplay(
            config.folder,
            config.left_topic,
            config.right_topic,
            left_info_topic=config.left_info_topic,
            right_info_topic=config.right_info_topic,
            rate_hz=config.rate_hz,
        )
    return sources.FolderReplay(config.folder, config.rate_hz)


def _geometry(config: CameraConfig, source, calibration):
    """(intrinsics, rectify function or None) for the open ``source``."""
    import dataclasses

    from companion.camera.calibration import Rectifier

    size = source.size_px
    if calibration is not None and getattr(source, "intrinsics", None) is not None:
        raise ValueError(
            f"{source.description}: the manifest's intrinsics say the pairs are already "
            "rectified; drop --calibration or the manifest's 'intrinsics'"
        )
    if calibration is not None:
        rectifier = Rectifier(calibration, size, config.alpha, config.output_size_px)
        return rectifier.intrinsics, rectifier.rectify, "calibration"
    intrinsics = config.intrinsics
    origin = "intrinsics"
    if intrinsics is None:
        intrinsics = getattr(source, "intrinsics", None)
        origin = "depth-camera" if config.source.kind is SourceKind.REALSENSE else "manifest"
        origin = "depth-camera" if config.source.depth_topic is not None else origin
        if intrinsics is None:
            raise ValueError(
                f"{source.description}: no intrinsics: give --calibration FILE (raw pairs) or "
                "--intrinsics / manifest.json 'intrinsics' (rectified pairs)"
            )
        if (intrinsics.width_px, intrinsics.height_px) != size:
            raise ValueError(
                f"manifest intrinsics are {intrinsics.width_px}x{intrinsics.height_px} but the "
                f"images are {size[0]}x{size[1]}"
            )
    else:
        intrinsics = dataclasses.replace(intrinsics, width_px=size[0], height_px=size[1])
    return intrinsics, None, origin


@dataclass
class _Stats:
    frames: int = 0
    publish_errors: int = 0
    first_ns: int | None = None
    last_ns: int | None = None
    lag_sum_ms: float = 0.0
    max_lag_ms: float = 0.0
    stopped_by: str = "end"

    def as_dict(self) -> dict:
        span_s = 0.0
        if self.first_ns is not None and self.last_ns is not None:
            span_s = (self.last_ns - self.first_ns) / 1e9
        rate = (self.frames - 1) / span_s if self.frames > 1 and span_s > 0 else 0.0
        return {
            "frames": self.frames,
            "publish_errors": self.publish_errors,
            "span_s": round(span_s, 3),
            "rate_hz": round(rate, 2),
            "mean_lag_ms": round(self.lag_sum_ms / self.frames, 3) if self.frames else 0.0,
            "max_lag_ms": round(self.max_lag_ms, 3),
            "stopped_by": self.stopped_by,
        }


def _frame(sequence: int, item, intrinsics, rectify):
    """The wire frame of one source item: a (rectified) stereo pair, or a depth camera's
    :class:`~companion.camera.depth_sources.RawDepth` as a depth frame."""
    from companion.camera.depth_sources import RawDepth
    from protocols.stereo_frame import DepthFrame, StereoFrame

    if isinstance(item, RawDepth):
        return DepthFrame(
            sequence,
            item.capture_ns,
            intrinsics,
            item.depth,
            item.encoding,
            item.depth_scale_m,
            item.left,
        )
    left, right = (item.left, item.right) if rectify is None else rectify(item.left, item.right)
    return StereoFrame(sequence, item.capture_ns, intrinsics, left, right)


def _sleep(seconds: float, should_stop: Callable[[], bool]) -> bool:
    """Sleep ``seconds`` in short slices; True if asked to stop meanwhile."""
    deadline = time.monotonic() + seconds
    while not should_stop():
        left = deadline - time.monotonic()
        if left <= 0:
            return False
        time.sleep(min(left, 0.01))
    return True


class CameraService:
    """Source → (rectify) → :class:`~protocols.frame_publisher.FramePublisher`, on the
    shared lifecycle (:func:`protocols.process.run_until_signalled`): :meth:`open`,
    :meth:`readiness_line`, :meth:`run`, :meth:`close` (returns the stats).

    Raises (from :meth:`open`)
    --------------------------
    companion.camera.sources.SourceError
        The source cannot deliver.
    companion.camera.calibration.CalibrationError, ValueError
        Bad calibration or intrinsics.
    zenoh.ZError
        The session cannot be opened.
    """

    def __init__(self, config: CameraConfig, clock: Callable[[], int] = time.monotonic_ns):
        from protocols.keys import stereo_key

        self.config = config
        self.clock = clock
        self.key = stereo_key(config.vehicle_id)
        self.stats = _Stats()
        self._source = None
        self._session = None
        self._publisher = None
        self._geometry = None

    def open(self) -> None:
        import zenoh

        from companion.camera.calibration import load_calibration
        from protocols.frame_publisher import FramePublisher

        config = self.config
        calibration = None
        if config.calibration_files:
            calibration = load_calibration(config.calibration_files, config.calibration_units)
        try:
            zenoh_conf = zenoh_config(config.zenoh)
        except zenoh.ZError as exc:
            raise ValueError(f"zenoh config: {exc}") from None
        self._source = make_source(config.source)
        self._source.open()
        self._geometry = _geometry(config, self._source, calibration)
        self._session = zenoh.open(zenoh_conf)
        # live: the newest frame matters; replay: deliver every recorded pair
        live = config.source.kind is not SourceKind.REPLAY and config.source.folder is None
        self._publisher = FramePublisher(self._session, self.key, drop=live)

    def readiness_line(self) -> str:
        intrinsics, _rectify, origin = self._geometry
        return (
            f"STEREO_CAMERA READY key={self.key} source={self._source.description} "
            f"size={intrinsics.width_px}x{intrinsics.height_px} rectify={origin} "
            f"zenoh={self.config.zenoh.describe()}"
        )

    def run(self, should_stop: Callable[[], bool]) -> None:
        """Publish until the source ends, ``max_frames`` or ``should_stop()``."""
        config, stats, clock = self.config, self.stats, self.clock
        intrinsics, rectify, _origin = self._geometry
        self._wait_for_subscriber(should_stop)
        stats.stopped_by = "signal"
        while not should_stop():
            pair = self._source.read()
            if pair is None:
                stats.stopped_by = "end"
                _sleep(_FLUSH_S, should_stop)
                return
            delay_ns = pair.capture_ns - clock()
            if delay_ns > 0 and _sleep(delay_ns / 1e9, should_stop):
                return
            if not self._publisher.publish_frame(_frame(stats.frames, pair, intrinsics, rectify)):
                stats.publish_errors += 1
            now = clock()
            lag_ms = (now - pair.capture_ns) / 1e6
            stats.lag_sum_ms += lag_ms
            stats.max_lag_ms = max(stats.max_lag_ms, lag_ms)
            stats.first_ns = stats.first_ns if stats.first_ns is not None else now
            stats.last_ns = now
            stats.frames += 1
            if config.max_frames is not None and stats.frames >= config.max_frames:
                stats.stopped_by = "max_frames"
                _sleep(_FLUSH_S, should_stop)
                return

    def _wait_for_subscriber(self, should_stop: Callable[[], bool]) -> None:
        timeout_s = self.config.wait_subscriber_s
        if timeout_s <= 0:
            return
        deadline = time.monotonic() + timeout_s
        logged = False
        while not should_stop() and not self._publisher.has_subscribers:
            if not logged:
                _log.info("waiting for a subscriber on %s", self.key)
                logged = True
            if time.monotonic() >= deadline:
                _log.warning("no subscriber after %.1f s: publishing anyway", timeout_s)
                return
            time.sleep(0.01)

    def close(self) -> dict:
        if self._publisher is not None:
            self._publisher.close()
        if self._session is not None:
            self._session.close()
        if self._source is not None:
            self._source.close()
        return self.stats.as_dict()


def _one_line(exc: BaseException) -> str:
    text = _RUST_LOCATION.sub("", " ".join(str(exc).split()))
    return text or type(exc).__name__


def main(argv: Sequence[str] | None = None) -> int:
    """Console entry point (``stereo-camera``); returns the exit status."""
    try:
        threads = configure_threads()
    except ValueError as exc:
        print(f"{_PROG}: configuration error: {exc}", file=sys.stderr)
        return 2
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=getattr(logging, args.log_level),
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    logging.getLogger("stereo_camera").debug("%s: %s", _PROG, threads.describe())
    import cv2
    import zenoh

    from companion.camera.calibration import CalibrationError
    from companion.camera.sources import SourceError

    if args.log_level != "DEBUG":  # OpenCV's own multi-line warnings would bury our one line
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    try:
        config = config_from_args(args)
    except (ValueError, OSError) as exc:
        print(f"{_PROG}: configuration error: {_one_line(exc)}", file=sys.stderr)
        return 2
    try:
        stats = run_until_signalled(
            CameraService(config), log_name="stereo-camera", ready_file=args.ready_file
        )
    except (CalibrationError, ValueError) as exc:
        print(f"{_PROG}: configuration error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except SourceError as exc:
        print(f"{_PROG}: camera error: {_one_line(exc)}", file=sys.stderr)
        return 1
    except zenoh.ZError as exc:
        print(f"{_PROG}: zenoh error: {_one_line(exc)}", file=sys.stderr)
        return 1
    except OSError as exc:
        print(f"{_PROG}: error: {_one_line(exc)}", file=sys.stderr)
        return 1
    print(f"STEREO_CAMERA STATS {json.dumps(stats)}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
