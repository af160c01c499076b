"""Stereo frame sources: two V4L2 cameras, one side-by-side UVC camera, a folder replay.

Contract (:class:`StereoSource`, checked by ``tests/test_stereo_camera_sources.py`` against
every implementation that can run without hardware)
-------------------------------------------------------------------------------------------
* ``open()`` acquires the device or files and raises :class:`SourceError` (one line, naming
  the device or file) if it cannot; afterwards ``size_px`` is each eye's ``(width, height)``
  (None before). A live camera may grab frames in ``open()`` to learn the size; those are
  not delivered (they would be stale).
* ``read()`` returns the next :class:`RawPair` or ``None`` at the end of a finite source
  (and ``None`` on every later call). Both images are ``(height, width)`` uint8 MONO8 of
  ``size_px``; ``capture_ns`` strictly increases and is on the host's monotonic clock
  (``time.monotonic_ns()``, DESIGN.md "One clock"). A pair may carry a ``capture_ns`` in the
  future (replay schedules): the caller publishes it no earlier than that. Failures raise
  :class:`SourceError`.
* ``close()`` releases everything; it is idempotent and safe after a failed ``open()``.
* ``description`` says what the source is (for the readiness line and messages).

Capture times
-------------
* Live cameras: ``time.monotonic_ns()`` right after ``VideoCapture.grab()`` returns; for two
  cameras the mean of the two grab times (both grabs happen before either decode, keeping the
  eyes close in time).
* Replay: the recorded timestamps mapped onto the monotonic clock at replay start (the first
  ``read()``): ``capture_ns = t_start + (stamp_i − stamp_0)``, or ``t_start + i / rate`` with
  a chosen rate. So the companion sees a live-like stream on its own clock.

Folder layouts for replay (first match wins)
--------------------------------------------
1. ``manifest.json``: ``{"pairs": [{"left": "l/0.png", "right": "r/0.png", "stamp_ns": 0},
   ...], "intrinsics": {...}}``; ``stamp_ns`` optional (then a rate is needed);
   ``intrinsics`` optional, the :class:`~protocols.camera.StereoIntrinsics` fields of pairs
   that are *already rectified* (e.g. rendered ones). Paths are relative to the folder.
2. ``left_<id>.<ext>`` + ``right_<id>.<ext>`` in the folder.
3. Subfolders ``left/`` + ``right/``, ``cam0/data/`` + ``cam1/data/`` (EuRoC) or
   ``image_0/`` + ``image_1/`` (KITTI) holding files with the same names.
In 2 and 3 an ``<id>`` that is an integer is the capture timestamp in nanoseconds (EuRoC's
convention); otherwise, or for frame indices, pass a rate.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, runtime_checkable

import cv2
import numpy as np

from protocols.camera import StereoIntrinsics

__all__ = [
    "IMAGE_SUFFIXES",
    "FolderReplay",
    "MemorySource",
    "RawPair",
    "SideBySideCamera",
    "SourceError",
    "StereoSource",
    "V4L2PairCamera",
    "to_mono8",
]

#: File suffixes the replay source reads (lower case).
IMAGE_SUFFIXES = (".png", ".pgm", ".ppm", ".bmp", ".jpg", ".jpeg", ".tif", ".tiff")
_SUBFOLDER_PAIRS = (("left", "right"), ("cam0/data", "cam1/data"), ("image_0", "image_1"))
_MANIFEST_KEYS = {"pairs", "intrinsics"}
_PAIR_KEYS = {"left", "right", "stamp_ns"}
_MIN_STAMP_STEP_NS = 1_000_000  # file-name stamps < 1 ms apart are frame indices, not ns


class SourceError(RuntimeError):
    """A camera or recording cannot deliver frames; the message names the device or file."""


@dataclass(frozen=True, eq=False)
class RawPair:
    """One unrectified pair from a source.

    Attributes
    ----------
    left, right : numpy.ndarray
        ``(height_px, width_px)`` uint8 grayscale images (MONO8); ``left`` is the reference.
    capture_ns : int
        Capture time [ns] on the host's monotonic clock (see the module docstring).
    """

    left: np.ndarray
    right: np.ndarray
    capture_ns: int


@runtime_checkable
class StereoSource(Protocol):
    """What the publisher needs from a frame source (contract in the module docstring)."""

    description: str

    @property
    def size_px(self) -> tuple[int, int] | None:
        """``(width, height)`` of each eye; None before :meth:`open`."""
        ...

    def open(self) -> None: ...

    def read(self) -> RawPair | None: ...

    def close(self) -> None: ...


def to_mono8(image: np.ndarray) -> np.ndarray:
    """Any OpenCV image (gray, BGR, BGRA; 8 or 16 bit) → ``(H, W)`` uint8 grayscale.

    Raises
    ------
    ValueError
        For shapes or dtypes that are not an image.
    """
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim == 3 and image.shape[2] in (3, 4):
        code = cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        image = cv2.cvtColor(image, code)
    if image.ndim != 2:
        raise ValueError(f"not an image: shape {image.shape}")
    if image.dtype == np.uint16:
        image = (image >> 8).astype(np.uint8)
    elif image.dtype != np.uint8:
        raise ValueError(f"unsupported pixel type {image.dtype} (need 8 or 16 bit)")
    return np.ascontiguousarray(image)


def _size_text(size: tuple[int, int]) -> str:
    return f"{size[0]}x{size[1]}"


def _shape_size(image: np.ndarray) -> tuple[int, int]:
    return int(image.shape[1]), int(image.shape[0])


# --------------------------------------------------------------------------- live cameras


def _parse_device(device: str | int) -> str | int:
    """``0`` / ``"0"`` → index 0; ``/dev/video0`` stays a path; anything else (a video file,
    a GStreamer pipeline) is passed to OpenCV as is."""
    if isinstance(device, int):
        return device
    text = str(device).strip()
    return int(text) if text.isdigit() else text


class _Capture:
    """One ``cv2.VideoCapture`` with the checks and settings a live stereo eye needs."""

    def __init__(
        self,
        label: str,
        device: str | int,
        size_px: tuple[int, int] | None,
        fps: float | None,
        fourcc: str | None,
        size_note: str = "",
    ) -> None:
        self.label = label
        self.size_note = size_note
        self.device = _parse_device(device)
        self.size_px = size_px
        self.fps = fps
        self.fourcc = fourcc
        self.is_v4l2 = isinstance(self.device, int) or str(self.device).startswith("/dev/")
        self._cap: cv2.VideoCapture | None = None

    @property
    def name(self) -> str:
        dev = f"/dev/video{self.device}" if isinstance(self.device, int) else self.device
        return f"{self.label} camera {dev}"

    def open(self) -> None:
        if self.is_v4l2:
            path = f"/dev/video{self.device}" if isinstance(self.device, int) else str(self.device)
            if os.name == "posix" and not os.path.exists(path):
                raise SourceError(f"{self.name}: device does not exist (is it plugged in?)")
            cap = cv2.VideoCapture(self.device, cv2.CAP_V4L2)
        else:
            cap = cv2.VideoCapture(str(self.device), cv2.CAP_ANY)
        if not cap.isOpened():
            cap.release()
            raise SourceError(f"{self.name}: cannot open (busy, no permission or not a camera)")
        self._cap = cap
        if self.is_v4l2:
            cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)  # freshest frame, lowest latency
            if self.fourcc:
                cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*self.fourcc))
            if self.size_px is not None:
                cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.size_px[0])
                cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.size_px[1])
            if self.fps is not None:
                cap.set(cv2.CAP_PROP_FPS, self.fps)

    def grab(self) -> bool:
        assert self._cap is not None, "open() first"
        return bool(self._cap.grab())

    def retrieve(self) -> np.ndarray:
        assert self._cap is not None, "open() first"
        ok, image = self._cap.retrieve()
        if not ok or image is None:
            raise SourceError(f"{self.name}: frame could not be decoded")
        try:
            return to_mono8(image)
        except ValueError as exc:
            raise SourceError(f"{self.name}: {exc}") from None

    def check_size(self, image: np.ndarray, expected: tuple[int, int] | None) -> None:
        if expected is not None and _shape_size(image) != expected:
            raise SourceError(
                f"{self.name}: delivers {_size_text(_shape_size(image))}, requested "
                f"{_size_text(expected)}{self.size_note} (mode not supported by the camera?)"
            )

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None


class _LiveCamera:
    """What the live cameras share: the size found on :meth:`open`, capture stamps from the
    injected clock made strictly increasing, and the end of a video file as the end."""

    description: str

    def _init_live(self, requested: tuple[int, int] | None, clock: Callable[[], int]) -> None:
        self._requested = requested
        self._clock = clock
        self._size: tuple[int, int] | None = None
        self._last_ns = -1
        self._ended = False

    @property
    def size_px(self) -> tuple[int, int] | None:
        return self._size

    def _read_pair(self) -> tuple[np.ndarray, np.ndarray, int] | None:
        """The next (left, right, capture time [ns]); None at the end of a file."""
        raise NotImplementedError

    def read(self) -> RawPair | None:
        if self._ended:
            return None
        pair = self._read_pair()
        if pair is None:
            self._ended = True
            return None
        left, right, capture_ns = pair
        capture_ns = max(capture_ns, self._last_ns + 1)
        self._last_ns = capture_ns
        return RawPair(left, right, capture_ns)


class V4L2PairCamera(_LiveCamera):
    """Two cameras (V4L2 index or ``/dev/videoN``; a video file or pipeline also works).

    Parameters
    ----------
    left_device, right_device : str or int
        Devices of the left (reference) and right eye.
    size_px : (int, int) or None
        Requested ``(width, height)`` of each eye; None keeps the camera's default.
    fps : float or None
        Requested frame rate [Hz].
    fourcc : str or None
        Requested pixel format, e.g. ``"MJPG"`` (USB 2 bandwidth) or ``"YUYV"``.
    clock : callable
        Monotonic clock [ns]; ``time.monotonic_ns`` (injectable for tests).
    """

    def __init__(
        self,
        left_device: str | int,
        right_device: str | int,
        size_px: tuple[int, int] | None = None,
        fps: float | None = None,
        fourcc: str | None = None,
        clock: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        self._eyes = (
            _Capture("left", left_device, size_px, fps, fourcc),
            _Capture("right", right_device, size_px, fps, fourcc),
        )
        self._init_live(size_px, clock)
        self.description = f"v4l2:{self._eyes[0].device},{self._eyes[1].device}"

    def open(self) -> None:
        try:
            for eye in self._eyes:
                eye.open()
            left, right, _ = self._grab_pair()
            if left is None or right is None:
                raise SourceError(f"{self.description}: no frame from the cameras")
            for eye, image in zip(self._eyes, (left, right), strict=True):
                eye.check_size(image, self._requested)
            if left.shape != right.shape:
                raise SourceError(
                    f"size mismatch between eyes: {self._eyes[0].name} gives "
                    f"{_size_text(_shape_size(left))}, {self._eyes[1].name} gives "
                    f"{_size_text(_shape_size(right))}"
                )
            self._size = _shape_size(left)
        except BaseException:
            self.close()
            raise

    def _grab_pair(self) -> tuple[np.ndarray | None, np.ndarray | None, int]:
        stamps = []
        for eye in self._eyes:
            if not eye.grab():
                if eye.is_v4l2:
                    raise SourceError(f"{eye.name}: grab failed (disconnected?)")
                return None, None, 0  # end of a video file
            stamps.append(self._clock())
        left, right = (eye.retrieve() for eye in self._eyes)
        return left, right, sum(stamps) // 2

    def _read_pair(self) -> tuple[np.ndarray, np.ndarray, int] | None:
        left, right, capture_ns = self._grab_pair()
        if left is None or right is None:
            return None
        for eye, image in zip(self._eyes, (left, right), strict=True):
            if _shape_size(image) != self._size:
                raise SourceError(
                    f"{eye.name}: frame size changed to {_size_text(_shape_size(image))}"
                )
        return left, right, capture_ns

    def close(self) -> None:
        for eye in self._eyes:
            eye.close()


class SideBySideCamera(_LiveCamera):
    """One UVC stereo camera delivering ``[left | right]`` in one frame of width ``2·W``.

    Parameters
    ----------
    device : str or int
        V4L2 index or ``/dev/videoN`` (a video file or pipeline also works).
    size_px : (int, int) or None
        Requested ``(width, height)`` of *each eye*; the camera is asked for ``2·width``.
    fps, fourcc, clock
        As for :class:`V4L2PairCamera`.
    """

    def __init__(
        self,
        device: str | int,
        size_px: tuple[int, int] | None = None,
        fps: float | None = None,
        fourcc: str | None = None,
        clock: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        full = (2 * size_px[0], size_px[1]) if size_px is not None else None
        note = f" (2 x {_size_text(size_px)} side by side)" if size_px is not None else ""
        self._cap = _Capture("side-by-side", device, full, fps, fourcc, note)
        self._init_live(full, clock)
        self.description = f"side-by-side:{self._cap.device}"

    def open(self) -> None:
        try:
            self._cap.open()
            frame = self._grab()
            if frame is None:
                raise SourceError(f"{self._cap.name}: no frame from the camera")
            self._cap.check_size(frame[0], self._requested)
            width, height = _shape_size(frame[0])
            if width % 2:
                raise SourceError(
                    f"{self._cap.name}: frame width {width} is odd, cannot split into two eyes"
                )
            self._size = (width // 2, height)
        except BaseException:
            self.close()
            raise

    def _grab(self) -> tuple[np.ndarray, int] | None:
        if not self._cap.grab():
            if self._cap.is_v4l2:
                raise SourceError(f"{self._cap.name}: grab failed (disconnected?)")
            return None
        capture_ns = self._clock()
        return self._cap.retrieve(), capture_ns

    def _read_pair(self) -> tuple[np.ndarray, np.ndarray, int] | None:
        frame = self._grab()
        if frame is None:
            return None
        image, capture_ns = frame
        w, h = self._size
        if _shape_size(image) != (2 * w, h):
            raise SourceError(
                f"{self._cap.name}: frame size changed to {_size_text(_shape_size(image))}"
            )
        return np.ascontiguousarray(image[:, :w]), np.ascontiguousarray(image[:, w:]), capture_ns

    def close(self) -> None:
        self._cap.close()


# --------------------------------------------------------------------------- replay


@dataclass(frozen=True)
class _Entry:
    left: Path
    right: Path
    stamp_ns: int | None


def _image_files(folder: Path, prefix: str = "") -> dict[str, Path]:
    """``{id: path}`` of the images in ``folder`` named ``<prefix><id>.<ext>``."""
    found: dict[str, Path] = {}
    if not folder.is_dir():
        return found
    for path in folder.iterdir():
        if (
            path.is_file()
            and path.suffix.lower() in IMAGE_SUFFIXES
            and path.stem.startswith(prefix)
            and len(path.stem) > len(prefix)
        ):
            found[path.stem[len(prefix) :]] = path
    return found


def _entries_from_names(lefts: dict[str, Path], rights: dict[str, Path]) -> list[_Entry]:
    unpaired = sorted(set(lefts) ^ set(rights))
    if unpaired:
        first = unpaired[0]
        path = lefts.get(first) or rights.get(first)
        raise SourceError(f"{path} has no partner image for the other eye")
    ids = list(lefts)
    if all(i.isdigit() for i in ids):
        ids.sort(key=int)
        return [_Entry(lefts[i], rights[i], int(i)) for i in ids]
    ids.sort()
    return [_Entry(lefts[i], rights[i], None) for i in ids]


def _load_manifest(folder: Path) -> tuple[list[_Entry], StereoIntrinsics | None]:
    path = folder / "manifest.json"
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise SourceError(f"{path}: cannot read manifest ({exc})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("pairs"), list):
        raise SourceError(f"{path}: expected an object with a 'pairs' list")
    unknown = sorted(set(doc) - _MANIFEST_KEYS)
    if unknown:
        raise SourceError(f"{path}: unknown key(s) {unknown}; valid: {sorted(_MANIFEST_KEYS)}")
    intrinsics = None
    if doc.get("intrinsics") is not None:
        try:
            intrinsics = StereoIntrinsics(**doc["intrinsics"])
        except (TypeError, ValueError) as exc:
            raise SourceError(f"{path}: bad intrinsics ({exc})") from None
    entries = []
    for n, item in enumerate(doc["pairs"]):
        if not isinstance(item, dict) or not {"left", "right"} <= set(item):
            raise SourceError(f"{path}: pairs[{n}] needs 'left' and 'right'")
        unknown = sorted(set(item) - _PAIR_KEYS)
        if unknown:
            raise SourceError(f"{path}: pairs[{n}] has unknown key(s) {unknown}")
        stamp = item.get("stamp_ns")
        if stamp is not None and (isinstance(stamp, bool) or not isinstance(stamp, int)):
            raise SourceError(f"{path}: pairs[{n}].stamp_ns must be an integer, got {stamp!r}")
        entries.append(_Entry(folder / item["left"], folder / item["right"], stamp))
    stamped = [e.stamp_ns is not None for e in entries]
    if any(stamped) and not all(stamped):
        raise SourceError(f"{path}: give stamp_ns for every pair or for none")
    return entries, intrinsics


def _discover(folder: Path) -> tuple[list[_Entry], StereoIntrinsics | None, str]:
    if (folder / "manifest.json").is_file():
        entries, intrinsics = _load_manifest(folder)
        return entries, intrinsics, "manifest.json"
    lefts, rights = _image_files(folder, "left_"), _image_files(folder, "right_")
    if lefts or rights:
        return _entries_from_names(lefts, rights), None, "left_*/right_*"
    for left_dir, right_dir in _SUBFOLDER_PAIRS:
        lefts, rights = _image_files(folder / left_dir), _image_files(folder / right_dir)
        if lefts or rights:
            return _entries_from_names(lefts, rights), None, f"{left_dir}/+{right_dir}/"
    return [], None, ""


class FolderReplay:
    """Replays recorded pairs from a folder at the recorded rate or at ``rate_hz``.

    Parameters
    ----------
    folder : path
        The recording (layouts in the module docstring).
    rate_hz : float or None
        Publish rate [Hz]; None replays at the recorded timestamps.
    clock : callable
        Monotonic clock [ns] the replay is mapped onto (``time.monotonic_ns``).

    Attributes
    ----------
    intrinsics : StereoIntrinsics or None
        Rectified intrinsics from the manifest (the pairs need no rectification), after open.
    """

    def __init__(
        self,
        folder: Path | str,
        rate_hz: float | None = None,
        clock: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        if rate_hz is not None and not (np.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"rate_hz must be finite and positive, got {rate_hz!r}")
        self.folder = Path(folder)
        self.rate_hz = rate_hz
        self._clock = clock
        self._entries: list[_Entry] = []
        self._size: tuple[int, int] | None = None
        self._next = 0
        self._start_ns: int | None = None
        self.intrinsics: StereoIntrinsics | None = None
        self.description = f"replay:{self.folder}"

    @property
    def size_px(self) -> tuple[int, int] | None:
        return self._size

    def __len__(self) -> int:
        return len(self._entries)

    def open(self) -> None:
        if not self.folder.is_dir():
            raise SourceError(f"replay folder {self.folder} does not exist")
        entries, intrinsics, layout = _discover(self.folder)
        if not entries:
            raise SourceError(
                f"no image pairs in {self.folder} (expected manifest.json, "
                "left_<stamp_ns>.png + right_<stamp_ns>.png, or left/ + right/ subfolders)"
            )
        if self.rate_hz is None:
            if entries[0].stamp_ns is None:
                raise SourceError(
                    f"{self.folder}: no timestamps in the {layout} names; choose a rate (--rate)"
                )
            steps = np.diff([e.stamp_ns for e in entries])
            if np.any(steps <= 0):
                raise SourceError(f"{self.folder}: timestamps are not strictly increasing")
            if layout != "manifest.json" and steps.size and np.median(steps) < _MIN_STAMP_STEP_NS:
                raise SourceError(
                    f"{self.folder}: file-name ids look like frame indices, not nanosecond "
                    "timestamps; choose a rate (--rate)"
                )
        self._entries = entries
        self.intrinsics = intrinsics
        self._size = None
        left, _right = self._load(entries[0])
        self._size = _shape_size(left)
        self._next = 0
        self._start_ns = None
        rate = f"{self.rate_hz:g} Hz" if self.rate_hz is not None else "recorded rate"
        self.description = f"replay:{self.folder} ({len(entries)} pairs, {rate})"

    def _load(self, entry: _Entry) -> tuple[np.ndarray, np.ndarray]:
        images = []
        for path in (entry.left, entry.right):
            image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED) if path.is_file() else None
            if image is None:
                raise SourceError(f"cannot read image {path} (missing or not an image)")
            try:
                images.append(to_mono8(image))
            except ValueError as exc:
                raise SourceError(f"{path}: {exc}") from None
        left, right = images
        if left.shape != right.shape:
            raise SourceError(
                f"size mismatch between eyes: {entry.left} is {_size_text(_shape_size(left))}, "
                f"{entry.right} is {_size_text(_shape_size(right))}"
            )
        if self._size is not None and _shape_size(left) != self._size:
            raise SourceError(
                f"{entry.left} is {_size_text(_shape_size(left))}, the recording is "
                f"{_size_text(self._size)}"
            )
        return left, right

    def read(self) -> RawPair | None:
        if self._next >= len(self._entries):
            return None
        i = self._next
        entry = self._entries[i]
        left, right = self._load(entry)
        if self._start_ns is None:
            self._start_ns = self._clock()
        if self.rate_hz is not None:
            offset_ns = round(i * 1e9 / self.rate_hz)
        else:
            offset_ns = entry.stamp_ns - self._entries[0].stamp_ns  # type: ignore[operator]
        self._next += 1
        return RawPair(left, right, self._start_ns + offset_ns)

    def close(self) -> None:
        self._entries = []
        self._next = 0


# --------------------------------------------------------------------------- in memory


class MemorySource:
    """Pairs held in memory, stamped ``t_start + i / rate_hz`` (a fake camera for tests).

    Parameters
    ----------
    pairs : sequence of (left, right)
        Images (any :func:`to_mono8` input) of equal size.
    rate_hz : float
        Nominal frame rate [Hz].
    clock : callable
        Monotonic clock [ns].
    """

    def __init__(
        self,
        pairs: Sequence[tuple[np.ndarray, np.ndarray]],
        rate_hz: float = 30.0,
        clock: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        self._pairs = list(pairs)
        self.rate_hz = rate_hz
        self._clock = clock
        self._size: tuple[int, int] | None = None
        self._next = 0
        self._start_ns: int | None = None
        self.description = f"memory:{len(self._pairs)} pairs"

    @property
    def size_px(self) -> tuple[int, int] | None:
        return self._size

    def open(self) -> None:
        if not self._pairs:
            raise SourceError("memory source holds no pairs")
        converted = [(to_mono8(np.asarray(a)), to_mono8(np.asarray(b))) for a, b in self._pairs]
        sizes = {_shape_size(img) for pair in converted for img in pair}
        if len(sizes) != 1:
            raise SourceError(f"size mismatch between eyes or pairs: {sorted(sizes)}")
        self._pairs = converted
        self._size = sizes.pop()
        self._next = 0
        self._start_ns = None

    def read(self) -> RawPair | None:
        if self._next >= len(self._pairs):
            return None
        if self._start_ns is None:
            self._start_ns = self._clock()
        left, right = self._pairs[self._next]
        capture_ns = self._start_ns + round(self._next * 1e9 / self.rate_hz)
        self._next += 1
        return RawPair(left, right, capture_ns)

    def close(self) -> None:
        self._next = len(self._pairs)
