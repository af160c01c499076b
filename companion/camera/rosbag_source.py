"""ROS 2 bags as a stereo source: ``stereo-camera replay BAG --left TOPIC --right TOPIC``.

Reads ``sensor_msgs/msg/Image`` pairs from a ROS 2 bag (sqlite3 or MCAP storage; ROS 1
bags too) with `rosbags <https://gitlab.com/ternaris/rosbags>`_ — no ROS installation. A
left and a right image are a pair when their ``header.stamp`` are within
``pair_tolerance_ns`` (stereo drivers stamp both eyes alike); unpaired images are counted
and skipped. Encodings: ``mono8``, ``mono16``, ``8UC1``, ``rgb8``, ``bgr8``, ``rgba8``,
``bgra8`` (converted to MONO8 like every other source).

The camera model comes from the bag's ``sensor_msgs/msg/CameraInfo`` (``--left-info`` /
``--right-info``; by default ``camera_info`` beside each image topic), read the ROS way
for a rectified pair: ``fx, fy, cx, cy`` from the left projection matrix ``P`` and the
baseline from the right one, ``B = −P_right[0,3] / P_right[0,0]``. Without CameraInfo give
``--intrinsics`` (rectified images) or ``--calibration`` (raw images), as for a folder.

Capture times: the header stamps, offset so that the first pair maps onto the host's
monotonic clock at the start of the replay (``rate_hz`` instead spaces them evenly), as
:class:`~companion.camera.sources.FolderReplay` does.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Iterator
from pathlib import Path

import cv2
import numpy as np

from companion.camera.sources import RawPair, SourceError, to_mono8
from protocols.camera import StereoIntrinsics

__all__ = [
    "Ros2BagReplay",
    "camera_info_matrix",
    "header_stamp_ns",
    "image_to_mono8",
    "intrinsics_from_camera_info",
    "open_bag",
]

_DEFAULT_TOLERANCE_NS = 1_000_000  # 1 ms
_COLOUR = {
    "rgb8": cv2.COLOR_RGB2GRAY,
    "bgr8": cv2.COLOR_BGR2GRAY,
    "rgba8": cv2.COLOR_RGBA2GRAY,
    "bgra8": cv2.COLOR_BGRA2GRAY,
}


def image_to_mono8(msg) -> np.ndarray:
    """A ``sensor_msgs/msg/Image`` → ``(height, width)`` uint8; ValueError if unsupported."""
    enc = str(msg.encoding).lower()
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8)
    if h <= 0 or w <= 0 or data.size < h * step:
        raise ValueError(f"image {w}x{h} step {step} with {data.size} bytes")
    rows = data[: h * step].reshape(h, step)
    if enc in ("mono8", "8uc1"):
        return np.ascontiguousarray(rows[:, :w])
    if enc in ("mono16", "16uc1"):
        dtype = ">u2" if msg.is_bigendian else "<u2"
        return to_mono8(rows[:, : 2 * w].copy().view(dtype).reshape(h, w).astype(np.uint16))
    if enc in _COLOUR:
        channels = 4 if enc.endswith("a8") else 3
        img = np.ascontiguousarray(rows[:, : channels * w]).reshape(h, w, channels)
        return cv2.cvtColor(img, _COLOUR[enc])
    raise ValueError(f"unsupported image encoding {msg.encoding!r}")


def camera_info_matrix(info, name: str, shape: tuple[int, int]) -> np.ndarray:
    """``CameraInfo``'s matrix ``name`` ("K", "P", ...) as floats of ``shape``: ROS 2 spells
    the fields in lower case (``p``), ROS 1 in upper case (``P``; a ROS 1 bag read through
    rosbags keeps ROS 1's names)."""
    values = getattr(info, name.lower(), None)
    if values is None:
        values = getattr(info, name.upper())
    return np.asarray(values, dtype=float).reshape(shape)


def intrinsics_from_camera_info(left_info, right_info) -> StereoIntrinsics:
    """Rectified stereo intrinsics from the two ``CameraInfo`` (ROS stereo convention)."""
    p_left = camera_info_matrix(left_info, "P", (3, 4))
    p_right = camera_info_matrix(right_info, "P", (3, 4))
    fx = p_left[0, 0]
    if not fx > 0:
        raise ValueError("left CameraInfo has no projection matrix P (fx = 0)")
    if not p_right[0, 0] > 0:
        raise ValueError("right CameraInfo has no projection matrix P (fx = 0)")
    baseline_m = -p_right[0, 3] / p_right[0, 0]
    if not baseline_m > 0:
        raise ValueError(
            f"right CameraInfo P[0,3] = {p_right[0, 3]!r} gives baseline {baseline_m!r} m: "
            "expected P[0,3] = -fx * baseline < 0 (rectified right camera)"
        )
    return StereoIntrinsics(
        int(left_info.width),
        int(left_info.height),
        float(fx),
        float(p_left[1, 1]),
        float(p_left[0, 2]),
        float(p_left[1, 2]),
        float(baseline_m),
    )


def header_stamp_ns(msg) -> int:
    """A stamped message's header time [ns]."""
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def open_bag(bag: Path):
    """An open ``rosbags`` reader over ``bag`` (ROS 2 folder, ``.db3``, ``.mcap`` or ROS 1
    ``.bag``; unknown message types default to ROS 2 Humble's), or a :class:`SourceError`
    that names it."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    if not bag.exists():
        raise SourceError(f"ROS bag {bag} does not exist")
    try:
        reader = AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as exc:  # rosbags raises its own error types on unreadable bags
        raise SourceError(f"cannot read ROS bag {bag}: {exc}") from None
    return reader


def _sibling_info(topic: str) -> str:
    return topic.rsplit("/", 1)[0] + "/camera_info" if "/" in topic.strip("/") else "camera_info"


class Ros2BagReplay:
    """A :class:`~companion.camera.sources.StereoSource` over two image topics of a bag.

    Parameters
    ----------
    bag : path
        Bag folder (``metadata.yaml`` + ``.db3``/``.mcap``) or a single ``.mcap``/``.db3``.
    left_topic, right_topic : str
        ``sensor_msgs/msg/Image`` topics.
    left_info_topic, right_info_topic : str or None
        ``sensor_msgs/msg/CameraInfo`` topics (default: ``camera_info`` beside the images);
        absent topics leave :attr:`intrinsics` None.
    rate_hz : float or None
        Publish rate; None = the recorded stamps.
    pair_tolerance_ns : int
        Left and right stamps this close are one pair.
    clock : callable
        Monotonic clock [ns] the replay is mapped onto.
    """

    def __init__(
        self,
        bag: Path | str,
        left_topic: str,
        right_topic: str,
        *,
        left_info_topic: str | None = None,
        right_info_topic: str | None = None,
        rate_hz: float | None = None,
        pair_tolerance_ns: int = _DEFAULT_TOLERANCE_NS,
        clock: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        if rate_hz is not None and not (np.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"rate_hz must be finite and positive, got {rate_hz!r}")
        if left_topic == right_topic:
            raise ValueError(f"--left and --right are the same topic {left_topic!r}")
        self.bag = Path(bag)
        self.topics = (left_topic, right_topic)
        self.info_topics = (
            left_info_topic or _sibling_info(left_topic),
            right_info_topic or _sibling_info(right_topic),
        )
        self.rate_hz = rate_hz
        self.pair_tolerance_ns = int(pair_tolerance_ns)
        self._clock = clock
        self._reader = None
        self._pairs: Iterator[tuple[int, np.ndarray, np.ndarray]] | None = None
        self._first: tuple[int, np.ndarray, np.ndarray] | None = None
        self._size: tuple[int, int] | None = None
        self._start_ns: int | None = None
        self._first_stamp_ns: int | None = None
        self._index = 0
        self.unpaired = 0
        self.intrinsics: StereoIntrinsics | None = None
        self.description = f"rosbag:{self.bag}"

    @property
    def size_px(self) -> tuple[int, int] | None:
        return self._size

    def open(self) -> None:
        reader = open_bag(self.bag)
        self._reader = reader
        by_topic = {c.topic: c for c in reader.connections}
        for topic in self.topics:
            conn = by_topic.get(topic)
            if conn is None:
                raise SourceError(f"{self.bag}: no topic {topic!r} (topics: {sorted(by_topic)})")
            if conn.msgtype != "sensor_msgs/msg/Image":
                raise SourceError(
                    f"{self.bag}: {topic} is {conn.msgtype}, not sensor_msgs/msg/Image"
                )
        self.intrinsics = self._read_intrinsics(by_topic)
        self._pairs = self._iter_pairs(by_topic)
        self._first = next(self._pairs, None)
        if self._first is None:
            raise SourceError(
                f"{self.bag}: no left/right pairs with stamps within "
                f"{self.pair_tolerance_ns / 1e6:g} ms on {self.topics[0]} and {self.topics[1]}"
            )
        h, w = self._first[1].shape
        self._size = (w, h)
        if (
            self.intrinsics is not None
            and (
                self.intrinsics.width_px,
                self.intrinsics.height_px,
            )
            != self._size
        ):
            raise SourceError(
                f"{self.bag}: CameraInfo is {self.intrinsics.width_px}x"
                f"{self.intrinsics.height_px} but the images are {w}x{h}"
            )
        rate = f"{self.rate_hz:g} Hz" if self.rate_hz is not None else "recorded rate"
        self.description = f"rosbag:{self.bag} ({self.topics[0]}, {self.topics[1]}, {rate})"

    def _read_intrinsics(self, by_topic) -> StereoIntrinsics | None:
        conns = [by_topic.get(t) for t in self.info_topics]
        if any(c is None or c.msgtype != "sensor_msgs/msg/CameraInfo" for c in conns):
            return None
        reader = self._reader
        infos = []
        for conn in conns:
            for c, _t, raw in reader.messages(connections=[conn]):
                infos.append(reader.deserialize(raw, c.msgtype))
                break
        if len(infos) != 2:
            return None
        try:
            return intrinsics_from_camera_info(*infos)
        except ValueError as exc:
            raise SourceError(f"{self.bag}: {exc}") from None

    def _iter_pairs(self, by_topic) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
        reader = self._reader
        left_conn, right_conn = by_topic[self.topics[0]], by_topic[self.topics[1]]
        pending: dict[str, deque] = {"left": deque(), "right": deque()}
        tol = self.pair_tolerance_ns
        for conn, _t, raw in reader.messages(connections=[left_conn, right_conn]):
            side = "left" if conn.topic == self.topics[0] else "right"
            other = "right" if side == "left" else "left"
            msg = reader.deserialize(raw, conn.msgtype)
            stamp = header_stamp_ns(msg)
            try:
                image = image_to_mono8(msg)
            except ValueError as exc:
                raise SourceError(f"{self.bag}: {conn.topic} at {stamp} ns: {exc}") from None
            queue = pending[other]
            while queue and queue[0][0] < stamp - tol:  # too old to ever pair
                queue.popleft()
                self.unpaired += 1
            if queue and abs(queue[0][0] - stamp) <= tol:
                other_stamp, other_image = queue.popleft()
                left, right = (image, other_image) if side == "left" else (other_image, image)
                if left.shape != right.shape:
                    raise SourceError(
                        f"{self.bag}: left and right images differ in size at {stamp} ns"
                    )
                yield min(stamp, other_stamp), left, right
            else:
                pending[side].append((stamp, image))
        self.unpaired += len(pending["left"]) + len(pending["right"])

    def read(self) -> RawPair | None:
        if self._first is not None:
            item, self._first = self._first, None
        elif self._pairs is not None:
            item = next(self._pairs, None)
        else:
            item = None
        if item is None:
            return None
        stamp, left, right = item
        if self._start_ns is None:
            self._start_ns = self._clock()
            self._first_stamp_ns = stamp
        if self.rate_hz is not None:
            offset_ns = round(self._index * 1e9 / self.rate_hz)
        else:
            offset_ns = stamp - self._first_stamp_ns  # type: ignore[operator]
        self._index += 1
        return RawPair(left, right, self._start_ns + offset_ns)

    def close(self) -> None:
        if self._reader is not None:
            self._reader.close()
            self._reader = None
        self._pairs = None
