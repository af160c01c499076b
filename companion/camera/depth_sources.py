"""Depth-camera sources for ``stereo-camera``: the camera computed the depth, we publish it.

Two sources deliver :class:`RawDepth` (a depth image registered to the camera's left
imager, optionally that imager's picture, a capture time on the host's monotonic clock);
:class:`~companion.camera.__main__.CameraService` publishes each as a
:class:`~protocols.stereo_frame.DepthFrame` (DEPTH16 or DEPTH32F) and the companion runs no
matcher on it.

:class:`Ros2DepthBagReplay` (``stereo-camera replay BAG --depth TOPIC --baseline M``)
    ``sensor_msgs/msg/Image`` depth topics of a ROS 2 bag (or ROS 1) through ``rosbags``,
    no ROS install: ``16UC1``/``mono16`` in millimetres (REP 118; 0 = no data) or ``32FC1``
    in metres (NaN = no data; REP 117's ±Inf, "no return in range" and "too close", become
    no data too: neither vouches for free space). Intrinsics from the depth topic's
    ``CameraInfo`` (``P``, else ``K``); a depth CameraInfo carries no stereo baseline, so
    ``--baseline`` states the camera's (D435 0.050 m, D455 0.095 m). ``--image TOPIC``
    adds the left imager's picture (paired by stamp) for the viewer. Capture times: the
    header stamps, mapped so the first frame lands on the host's monotonic clock at the
    start of the replay, as every replay source does. A RealSense ROS 1 recording (``.bag``)
    is read this way too, without pyrealsense2 (``--depth
    /device_0/sensor_0/Depth_0/image/data --depth-info
    /device_0/sensor_0/Depth_0/info/camera_info``): its depth units are the frame's own
    (SDK 2.49 and later append them, float32 [m], after the image's data, which rosbags
    alone refuses), else the recording's "Depth Units" option, else millimetres.

:class:`RealSenseSource` (``stereo-camera realsense [--bag FILE]``)
    An Intel RealSense D4xx through ``pyrealsense2``, or a recording its playback opens.
    The depth stream and infrared 1 (the left imager: RealSense's depth is registered to
    it pixel for pixel, so no ``rs.align`` is needed), the depth stream's intrinsics from
    the device, the depth scale from the depth sensor, the baseline from the infrared 1 →
    2 extrinsics (or the ``stereo_baseline`` option, or ``--baseline``). Live device
    timestamps are mapped onto the host's monotonic clock by the smallest observed
    (arrival − device time) offset, which converges to the transport's minimum latency
    and never lets a frame look younger than it is; a recording's timestamps are mapped
    like a replay's.
"""

from __future__ import annotations

import math
import struct
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from companion.camera.rosbag_source import (
    camera_info_matrix,
    header_stamp_ns,
    image_to_mono8,
    open_bag,
)
from companion.camera.sources import SourceError
from protocols.camera import StereoIntrinsics
from protocols.stereo_frame import PixelEncoding

__all__ = [
    "DepthFrameSource",
    "RawDepth",
    "Ros2DepthBagReplay",
    "depth_from_image_msg",
    "intrinsics_from_depth_info",
]

_MM = 0.001  # REP 118: 16UC1 depth images are in millimetres
_DEFAULT_TOLERANCE_NS = 1_000_000  # depth and picture stamps this close are one frame


@dataclass(frozen=True, eq=False)
class RawDepth:
    """One depth image from a depth camera.

    Attributes
    ----------
    depth : numpy.ndarray
        ``(height, width)``: uint16 units of ``depth_scale_m`` (0 = no data) or float32
        metres (NaN = no data), along the left imager's optical axis.
    encoding : PixelEncoding
        DEPTH16 or DEPTH32F.
    depth_scale_m : float
        Metres per unit (DEPTH16); 1 for DEPTH32F.
    left : numpy.ndarray or None
        The left imager's MONO8 picture, if the source has one.
    capture_ns : int
        Capture time on the host's monotonic clock [ns].
    """

    depth: np.ndarray
    encoding: PixelEncoding
    depth_scale_m: float
    left: np.ndarray | None
    capture_ns: int


@runtime_checkable
class DepthFrameSource(Protocol):
    """What the publisher needs from a depth camera source, as
    :class:`~companion.camera.sources.StereoSource` for pairs: ``size_px`` and
    ``intrinsics`` (with the stereo baseline the depth is equivalent to) are None until
    :meth:`open`; :meth:`read` gives each frame once, capture times strictly increasing,
    then None for good (end of a recording); :meth:`close` may be called more than once.
    ``tests/test_depth_camera_sources.py`` runs every implementation it finds against it."""

    description: str
    intrinsics: StereoIntrinsics | None

    @property
    def size_px(self) -> tuple[int, int] | None:
        """``(width, height)`` of the depth image; None before :meth:`open`."""
        ...

    def open(self) -> None: ...

    def read(self) -> RawDepth | None: ...

    def close(self) -> None: ...


def depth_from_image_msg(msg) -> tuple[np.ndarray, PixelEncoding, float]:
    """A ``sensor_msgs/msg/Image`` depth image → (plane, encoding, metres per unit).

    ``16UC1``/``mono16``: uint16 millimetres (DEPTH16, scale 0.001); ``32FC1``: float32
    metres (DEPTH32F) with every non-finite or negative value made NaN (no data).

    Raises
    ------
    ValueError
        Another encoding, or a size or byte count that does not add up.
    """
    enc = str(msg.encoding).lower()
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8)
    if h <= 0 or w <= 0 or data.size < h * step:
        raise ValueError(f"depth image {w}x{h} step {step} with {data.size} bytes")
    rows = data[: h * step].reshape(h, step)
    order = ">" if msg.is_bigendian else "<"
    if enc in ("16uc1", "mono16"):
        if step < 2 * w:
            raise ValueError(f"16UC1 depth image {w} px wide with a step of {step} bytes")
        plane = rows[:, : 2 * w].copy().view(f"{order}u2").reshape(h, w).astype(np.uint16)
        return plane, PixelEncoding.DEPTH16, _MM
    if enc == "32fc1":
        if step < 4 * w:
            raise ValueError(f"32FC1 depth image {w} px wide with a step of {step} bytes")
        plane = rows[:, : 4 * w].copy().view(f"{order}f4").reshape(h, w).astype(np.float32)
        plane[~((plane >= 0.0) & np.isfinite(plane))] = np.nan
        return plane, PixelEncoding.DEPTH32F, 1.0
    raise ValueError(f"unsupported depth encoding {msg.encoding!r} (16UC1, mono16 or 32FC1)")


def intrinsics_from_depth_info(info, baseline_m: float) -> StereoIntrinsics:
    """The depth image's camera from its ``CameraInfo`` (``P`` if set, else ``K``) and the
    camera's stereo baseline [m] (not in a depth CameraInfo)."""
    p = camera_info_matrix(info, "P", (3, 4))
    k = camera_info_matrix(info, "K", (3, 3))
    m = p[:, :3] if p[0, 0] > 0 else k
    if not m[0, 0] > 0 or not m[1, 1] > 0:
        raise ValueError("depth CameraInfo has neither P nor K (fx = 0)")
    if not (math.isfinite(baseline_m) and baseline_m > 0):
        raise ValueError(f"baseline must be finite and > 0 m, got {baseline_m!r}")
    return StereoIntrinsics(
        int(info.width),
        int(info.height),
        float(m[0, 0]),
        float(m[1, 1]),
        float(m[0, 2]),
        float(m[1, 2]),
        float(baseline_m),
    )


class _ReplayClock:
    """Recorded stamps → the host's monotonic clock: the first lands at the first read,
    the others keep their spacing (or ``rate_hz``'s)."""

    def __init__(self, rate_hz: float | None, clock: Callable[[], int]) -> None:
        if rate_hz is not None and not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"rate_hz must be finite and positive, got {rate_hz!r}")
        self.rate_hz = rate_hz
        self._clock = clock
        self._start: tuple[int, int] | None = None
        self._index = 0

    def capture_ns(self, stamp_ns: int) -> int:
        if self._start is None:
            self._start = (self._clock(), stamp_ns)
        start_ns, first_stamp_ns = self._start
        if self.rate_hz is not None:
            offset_ns = round(self._index * 1e9 / self.rate_hz)
        else:
            offset_ns = stamp_ns - first_stamp_ns
        self._index += 1
        return start_ns + offset_ns


class Ros2DepthBagReplay:
    """Depth frames from a ROS bag's depth image topic (module docstring).

    Parameters
    ----------
    bag : path
        Bag folder, ``.db3`` or ``.mcap`` (ROS 1 ``.bag`` too).
    depth_topic : str
        ``sensor_msgs/msg/Image`` (16UC1, mono16 or 32FC1).
    baseline_m : float
        The depth camera's stereo baseline [m].
    info_topic : str or None
        ``sensor_msgs/msg/CameraInfo`` of the depth image (default: ``camera_info`` beside).
    image_topic : str or None
        The left imager's picture, paired with the depth by stamp (optional).
    rate_hz : float or None
        Publish rate; None = the recorded stamps.
    clock : callable
        Monotonic clock [ns] the replay is mapped onto.
    """

    def __init__(
        self,
        bag: Path | str,
        depth_topic: str,
        baseline_m: float,
        *,
        info_topic: str | None = None,
        image_topic: str | None = None,
        rate_hz: float | None = None,
        clock: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        self.bag = Path(bag)
        self.depth_topic = depth_topic
        self.info_topic = info_topic or (depth_topic.rsplit("/", 1)[0] + "/camera_info")
        self.image_topic = image_topic
        self.baseline_m = float(baseline_m)
        self._time = _ReplayClock(rate_hz, clock)
        self._reader = None
        self._frames: Iterator[tuple[int, np.ndarray, PixelEncoding, float, object]] | None = None
        self._first = None
        self._units_m: float | None = None  # a RealSense recording's Depth Units option
        self.intrinsics: StereoIntrinsics | None = None
        self.unpaired = 0
        self.description = f"rosbag-depth:{self.bag}"

    @property
    def size_px(self) -> tuple[int, int] | None:
        k = self.intrinsics
        return None if k is None else (k.width_px, k.height_px)

    def open(self) -> None:
        self._reader = open_bag(self.bag)
        try:
            self._check_and_start()
        except SourceError:
            self.close()  # the reader holds the bag's files open
            raise

    def _check_and_start(self) -> None:
        """Check the topics, read the intrinsics and the first frame (after open)."""
        reader = self._reader
        by_topic = {c.topic: c for c in reader.connections}
        wanted = {self.depth_topic: "sensor_msgs/msg/Image", self.info_topic: None}
        if self.image_topic is not None:
            wanted[self.image_topic] = "sensor_msgs/msg/Image"
        for topic, msgtype in wanted.items():
            conn = by_topic.get(topic)
            if conn is None:
                raise SourceError(f"{self.bag}: no topic {topic!r} (topics: {sorted(by_topic)})")
            if msgtype is not None and conn.msgtype != msgtype:
                raise SourceError(f"{self.bag}: {topic} is {conn.msgtype}, not {msgtype}")
        self._units_m = self._recorded_depth_units(by_topic)
        info = self._first_message(by_topic[self.info_topic])
        try:
            self.intrinsics = intrinsics_from_depth_info(info, self.baseline_m)
        except (ValueError, AttributeError) as exc:
            raise SourceError(f"{self.bag}: {self.info_topic}: {exc}") from None
        self._frames = self._iter_frames(by_topic)
        self._first = next(self._frames, None)
        if self._first is None:
            raise SourceError(f"{self.bag}: no depth images on {self.depth_topic}")
        rate = "recorded rate" if self._time.rate_hz is None else f"{self._time.rate_hz:g} Hz"
        self.description = f"rosbag-depth:{self.bag} ({self.depth_topic}, {rate})"

    def _first_message(self, conn):
        for c, _t, raw in self._reader.messages(connections=[conn]):
            return self._reader.deserialize(raw, c.msgtype)
        raise SourceError(f"{self.bag}: no message on {conn.topic}")

    def _recorded_depth_units(self, by_topic) -> float | None:
        """A RealSense recording's "Depth Units" option [m] of the depth topic's sensor
        (``/device_0/sensor_0/option/Depth_Units/value``), None for other bags."""
        parts = self.depth_topic.split("/")
        conn = by_topic.get("/".join(parts[:3]) + "/option/Depth_Units/value")
        if len(parts) < 4 or conn is None or conn.msgtype != "std_msgs/msg/Float32":
            return None
        units = float(self._first_message(conn).data)
        if not (math.isfinite(units) and units > 0):
            raise SourceError(f"{self.bag}: {conn.topic} = {units!r} is not a depth unit")
        return units

    def _deserialize(self, conn, raw):
        """The message, and the depth units [m] a RealSense ROS 1 recording appended after
        an image's data (SDK 2.49 and later; the header's ``frame_id``, librealsense's
        "version", says "1"), else None."""
        try:
            return self._reader.deserialize(raw, conn.msgtype), None
        except Exception as exc:  # rosbags' own error for the 4 bytes it does not expect
            if conn.msgtype != "sensor_msgs/msg/Image" or len(raw) < 4:
                raise SourceError(f"{self.bag}: {conn.topic}: {exc}") from None
            try:
                msg = self._reader.deserialize(raw[:-4], conn.msgtype)
            except Exception:
                msg = None
            if msg is None or msg.header.frame_id != "1":
                raise SourceError(f"{self.bag}: {conn.topic}: {exc}") from None
            return msg, float(struct.unpack("<f", bytes(raw[-4:]))[0])

    def _iter_frames(self, by_topic):
        reader = self._reader
        conns = [by_topic[self.depth_topic]]
        if self.image_topic is not None:
            conns.append(by_topic[self.image_topic])
        pictures: deque = deque()
        depths: deque = deque()
        k = self.intrinsics
        for conn, _t, raw in reader.messages(connections=conns):
            msg, frame_units_m = self._deserialize(conn, raw)
            stamp = header_stamp_ns(msg)
            try:
                if conn.topic == self.depth_topic:
                    plane, encoding, scale = depth_from_image_msg(msg)
                    units_m = frame_units_m or self._units_m
                    if encoding is PixelEncoding.DEPTH16 and units_m is not None:
                        if not (math.isfinite(units_m) and units_m > 0):
                            raise ValueError(f"depth units {units_m!r} m")
                        scale = units_m  # RealSense's, where REP 118 says millimetres
                    if plane.shape != (k.height_px, k.width_px):
                        raise ValueError(
                            f"depth image is {plane.shape[1]}x{plane.shape[0]}, CameraInfo "
                            f"{k.width_px}x{k.height_px}"
                        )
                    depths.append((stamp, plane, encoding, scale))
                else:
                    pictures.append((stamp, image_to_mono8(msg)))
            except ValueError as exc:
                raise SourceError(f"{self.bag}: {conn.topic} at {stamp} ns: {exc}") from None
            yield from self._pair(depths, pictures)
        yield from self._pair(depths, pictures, final=True)

    def _pair(self, depths: deque, pictures: deque, final: bool = False):
        """Depth frames whose picture has come (or cannot come any more)."""
        while depths:
            stamp, plane, encoding, scale = depths[0]
            if self.image_topic is None:
                depths.popleft()
                yield stamp, plane, encoding, scale, None
                continue
            while pictures and pictures[0][0] < stamp - _DEFAULT_TOLERANCE_NS:
                pictures.popleft()
            if pictures and abs(pictures[0][0] - stamp) <= _DEFAULT_TOLERANCE_NS:
                depths.popleft()
                picture = pictures.popleft()[1]
                if picture.shape != plane.shape:
                    picture = None  # another resolution: not the registered left imager
                yield stamp, plane, encoding, scale, picture
            elif final or pictures:  # the picture for this stamp is past or never comes
                depths.popleft()
                self.unpaired += 1
                yield stamp, plane, encoding, scale, None
            else:
                return

    def read(self) -> RawDepth | None:
        item, self._first = (self._first, None) if self._first is not None else (None, None)
        if item is None and self._frames is not None:
            item = next(self._frames, None)
        if item is None:
            return None
        stamp, plane, encoding, scale, picture = item
        return RawDepth(plane, encoding, scale, picture, self._time.capture_ns(stamp))

    def close(self) -> None:
        if self._reader is not None:
            self._reader.close()
            self._reader = None
        self._frames = None
