"""``stereo-camera``'s configuration: where frames come from and where they go.

:class:`SourceKind`, :class:`SourceConfig` and :class:`CameraConfig` are built from the
command line by :func:`companion.camera.__main__.config_from_args`, the one place flags
become config; :func:`depth_camera_config` is its part for depth cameras (issue 35).
"""

from __future__ import annotations

import argparse
import enum
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from protocols.config import ConfigError, bounded, check_fields
from protocols.process import default_listen
from protocols.zenoh_session import ZenohSettings

if TYPE_CHECKING:  # numpy & co. load inside main(), after OPENBLAS_NUM_THREADS is set
    from protocols.camera import StereoIntrinsics

__all__ = ["CameraConfig", "SourceConfig", "SourceKind", "depth_camera_config"]


class SourceKind(enum.Enum):
    """Where frames come from."""

    V4L2_PAIR = "v4l2"  # two cameras
    SIDE_BY_SIDE = "sbs"  # one camera, [left | right] in one frame
    REPLAY = "replay"  # folder of recorded pairs, or a ROS bag (pairs or a depth topic)
    REALSENSE = "realsense"  # Intel RealSense depth camera or its recording (depth frames)


@dataclass(frozen=True)
class SourceConfig:
    """Frame source settings.

    Attributes
    ----------
    kind : SourceKind
    devices : tuple of str
        ``(left, right)`` for V4L2_PAIR, ``(device,)`` for SIDE_BY_SIDE (index, /dev/videoN,
        or anything ``cv2.VideoCapture`` opens).
    folder : Path or None
        Recording for REPLAY.
    size_px : (int, int) or None
        Requested per-eye ``(width, height)`` of live cameras.
    fps : float or None
        Requested camera rate [Hz].
    fourcc : str or None
        Requested camera pixel format (e.g. MJPG).
    rate_hz : float or None
        Replay rate [Hz]; None = recorded timestamps.
    left_topic, right_topic : str or None
        With REPLAY: ``folder`` is a ROS 2 bag and these are its image topics
        (:mod:`companion.camera.rosbag_source`).
    left_info_topic, right_info_topic : str or None
        CameraInfo topics of the bag (default: ``camera_info`` beside the images).
    depth_topic, depth_info_topic, image_topic : str or None
        With REPLAY: ``folder`` is a ROS bag with a depth image topic, its CameraInfo and
        optionally the left imager's picture (:mod:`companion.camera.depth_sources`).
    baseline_m : float or None
        A depth camera's stereo baseline [m] (ROS depth bags; RealSense override).
    with_image : bool
        REALSENSE: publish infrared 1 beside the depth.
    """

    kind: SourceKind
    devices: tuple[str, ...] = ()
    folder: Path | None = None
    size_px: tuple[int, int] | None = None
    fps: float | None = bounded(None, "Hz", gt=0, optional=True)
    fourcc: str | None = None
    rate_hz: float | None = bounded(None, "Hz", gt=0, optional=True)
    left_topic: str | None = None
    right_topic: str | None = None
    left_info_topic: str | None = None
    right_info_topic: str | None = None
    depth_topic: str | None = None
    depth_info_topic: str | None = None
    image_topic: str | None = None
    baseline_m: float | None = bounded(None, "m", gt=0, optional=True)
    with_image: bool = True

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class CameraConfig:
    """Everything ``run`` needs (built from the command line by :func:`config_from_args`).

    Attributes
    ----------
    source : SourceConfig
    vehicle_id : str
        Key chunk of ``stereo_avoid/<vehicle_id>/stereo``.
    zenoh : ZenohSettings
    calibration_files : tuple of Path
        OpenCV stereo calibration file(s); empty if the input is already rectified.
    calibration_units : str or None
        Unit of the calibration's ``T`` (m, cm, mm); None = the file's or metres.
    intrinsics : StereoIntrinsics or None
        Intrinsics of an already rectified input (no remap).
    alpha : float
        ``cv2.stereoRectify`` free scaling (0 = valid pixels only, 1 = all; -1 = OpenCV's
        default).
    output_size_px : (int, int) or None
        Rectified ``(width, height)``; default the input size.
    wait_subscriber_s : float
        How long to wait for a matching subscriber before the first frame [s] (inf = until
        one appears or a signal; 0 = do not wait).
    max_frames : int or None
        Stop after publishing this many frames.
    """

    source: SourceConfig
    vehicle_id: str = "sim1"
    zenoh: ZenohSettings = field(default_factory=ZenohSettings)
    calibration_files: tuple[Path, ...] = ()
    calibration_units: str | None = None
    intrinsics: StereoIntrinsics | None = None
    alpha: float = bounded(0.0, ge=-1, le=1)
    output_size_px: tuple[int, int] | None = None
    wait_subscriber_s: float = bounded(0.0, "s", ge=0, finite=False)
    max_frames: int | None = bounded(None, integer=True, ge=1, optional=True)

    def __post_init__(self) -> None:
        check_fields(self)
        if -1.0 < self.alpha < 0.0:
            raise ConfigError(f"must be -1 or in [0, 1], got {self.alpha!r}", key="alpha")


def depth_camera_config(kind: SourceKind, args: argparse.Namespace) -> CameraConfig:
    """A depth camera's :class:`CameraConfig`: no calibration or rectification (the camera
    computed the depth in its own rectified frame), intrinsics from the device or CameraInfo."""
    if args.calibration or args.intrinsics or args.output_size is not None:
        raise ValueError(
            "a depth camera takes no --calibration/--intrinsics/--output-size: its depth is "
            "rectified and its intrinsics come from the device or the CameraInfo"
        )
    if kind is SourceKind.REPLAY:
        if args.left is not None or args.right is not None:
            raise ValueError("give --depth TOPIC or --left/--right TOPIC, not both")
        if args.baseline is None:
            raise ValueError(
                "a depth bag needs --baseline M: a depth CameraInfo carries no stereo "
                "baseline (D435 0.050, D455 0.095)"
            )
        from companion.viz.options import require_extra

        require_extra("a ROS bag (--depth)", "rosbags", "rosbags")
        source = SourceConfig(
            kind,
            folder=args.folder,
            rate_hz=args.rate,
            depth_topic=args.depth,
            depth_info_topic=args.depth_info,
            image_topic=args.image,
            baseline_m=args.baseline,
        )
    else:
        source = SourceConfig(
            kind,
            folder=args.bag,
            size_px=args.size,
            fps=args.fps,
            rate_hz=args.rate,
            baseline_m=args.baseline,
            with_image=not args.no_image,
        )
    replay = kind is SourceKind.REPLAY or args.bag is not None
    wait = args.wait_subscriber
    if wait is None:
        wait = math.inf if replay else 0.0
    from protocols.keys import validate_vehicle_id

    listen = default_listen(args.zenoh_listen, args.zenoh_connect, args.zenoh_config)
    if args.zenoh_config is not None and not args.zenoh_config.is_file():
        raise ValueError(f"--zenoh-config {args.zenoh_config} does not exist")
    return CameraConfig(
        source=source,
        vehicle_id=validate_vehicle_id(args.vehicle_id),
        zenoh=ZenohSettings(
            listen=listen, connect=tuple(args.zenoh_connect), config_file=args.zenoh_config
        ),
        wait_subscriber_s=wait,
        max_frames=args.max_frames,
    )
