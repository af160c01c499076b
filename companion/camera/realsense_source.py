"""``stereo-camera realsense``: an Intel RealSense D4xx (or a recording of one) as a depth source.

See :mod:`companion.camera.depth_sources` for what is published. Through ``pyrealsense2``
(Intel's Python wrapper, ``pip install pyrealsense2``; it needs ``libusb-1.0``): the depth
stream (Z16) and infrared 1, the left imager depth is registered to, at one size and rate;
the depth stream's intrinsics and the depth sensor's depth scale from the device; the
baseline from the infrared 1 → infrared 2 extrinsics, else the depth sensor's
``stereo_baseline`` option [mm], else ``--baseline``.

Depth units: each depth frame's own (``depth_frame.get_units()``; a recording made before
SDK 2.49 has none in its frames and playback gives the depth sensor's "Depth Units"
option), else the depth sensor's depth scale.

End of a recording: no frame within ``_POLL_MS`` while the playback says it has stopped,
and none in a last ``_DRAIN_MS`` wait (or none for ``_WAIT_MS`` whatever it says).

Time: a recording (``--bag FILE``: whatever pyrealsense2's playback opens; version 2.59
records only ROS 2 ``.db3`` and still plays the ROS 1 ``.bag`` of older SDKs, which is
what existing recordings are) is read as fast as it is
consumed and its frame timestamps are mapped like a replay's (the first lands on the
host's monotonic clock at the first read). A live device's timestamps (hardware clock or
global time, in ms) are mapped onto the host's monotonic clock by the smallest
``arrival − device time`` of the last ``_OFFSET_WINDOW`` frames: that offset is the device
clock's position plus the transport's minimum latency, so a frame never looks younger than
it is, and the window follows the two clocks' drift.

What could not be tested here (no device on CI): live streaming, USB behaviour, the
extrinsics of a real module. The recorded path is tested with a ``.db3`` made by
pyrealsense2's software device under its own recorder and a ROS 1 ``.bag`` written in
librealsense's layout without the SDK (tests/test_depth_camera_sources.py).
"""

from __future__ import annotations

import contextlib
import math
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path

import numpy as np

from companion.camera.depth_sources import RawDepth, _ReplayClock
from companion.camera.sources import SourceError
from protocols.camera import StereoIntrinsics
from protocols.stereo_frame import PixelEncoding

__all__ = ["RealSenseSource"]

_WAIT_MS = 2000  # one frame wait; a recording that delivers nothing this long has ended
_POLL_MS = 50  # recording: a wait this long, then ask the playback whether it has stopped
_DRAIN_MS = 300  # a stopped playback's last wait for frames still on their way
_LIVE_TIMEOUT_S = 5.0  # a live device silent this long is an error
_OFFSET_WINDOW = 300  # frames of (arrival - device time) the clock offset is the minimum of


def _baseline_m(rs, profile, explicit_m: float | None) -> float:
    """The stereo baseline [m]: ``explicit_m``, else the infrared 1 → 2 extrinsics, else the
    depth sensor's ``stereo_baseline`` option [mm]."""
    if explicit_m is not None:
        return explicit_m
    streams = {(s.stream_type(), s.stream_index()): s for s in profile.get_streams()}
    ir1 = streams.get((rs.stream.infrared, 1))
    ir2 = streams.get((rs.stream.infrared, 2))
    if ir1 is not None and ir2 is not None:
        try:
            baseline = abs(float(ir1.get_extrinsics_to(ir2).translation[0]))
            if baseline > 0:
                return baseline
        except RuntimeError:
            pass
    sensor = profile.get_device().first_depth_sensor()
    if sensor.supports(rs.option.stereo_baseline):
        baseline = float(sensor.get_option(rs.option.stereo_baseline)) / 1000.0
        if baseline > 0:
            return baseline
    raise SourceError(
        "the RealSense reports no stereo baseline (no infrared 2 extrinsics, no "
        "stereo_baseline option): give --baseline M (D435 0.050, D455 0.095)"
    )


class RealSenseSource:
    """Depth (and the left infrared picture) from a RealSense device or recording.

    Parameters
    ----------
    bag : path or None
        A recording to play back; None opens the first connected device.
    size_px : (int, int) or None
        Live: requested depth/infrared size (default 640 × 480).
    fps : float or None
        Live: requested rate [Hz] (default 30).
    baseline_m : float or None
        Override of the device's stereo baseline [m].
    with_image : bool
        Publish infrared 1 beside the depth (for the viewer).
    rate_hz : float or None
        Recording: publish rate instead of the recorded timestamps.
    clock : callable
        Host monotonic clock [ns].
    """

    def __init__(
        self,
        bag: Path | str | None = None,
        *,
        size_px: tuple[int, int] | None = None,
        fps: float | None = None,
        baseline_m: float | None = None,
        with_image: bool = True,
        rate_hz: float | None = None,
        clock: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        if baseline_m is not None and not (math.isfinite(baseline_m) and baseline_m > 0):
            raise ValueError(f"--baseline must be finite and > 0 m, got {baseline_m!r}")
        self.bag = None if bag is None else Path(bag)
        self.size_px_requested = size_px or (640, 480)
        self.fps = round(fps) if fps is not None else 30
        self.baseline_override_m = baseline_m
        self.with_image = with_image
        self._clock = clock
        self._replay = _ReplayClock(rate_hz, clock) if self.bag is not None else None
        self._offsets: deque[int] = deque(maxlen=_OFFSET_WINDOW)
        self._pipeline = None
        self._has_ir1 = False
        self._last_frame_number: int | None = None
        self._ended = False  # a recording that has ended stays ended (no more waits)
        self._playback_stopped: Callable[[], bool] = lambda: False
        self.depth_scale_m = 0.001
        self.intrinsics: StereoIntrinsics | None = None
        self.description = "realsense"

    @property
    def size_px(self) -> tuple[int, int] | None:
        k = self.intrinsics
        return None if k is None else (k.width_px, k.height_px)

    def open(self) -> None:
        try:
            import pyrealsense2 as rs
        except ImportError as exc:
            raise SourceError(
                f"pyrealsense2 is not usable ({exc}): pip install pyrealsense2 (and the "
                "libusb-1.0 system library)"
            ) from None
        config = rs.config()
        if self.bag is not None:
            if not self.bag.exists():
                raise SourceError(f"RealSense recording {self.bag} does not exist")
            rs.config.enable_device_from_file(config, str(self.bag), repeat_playback=False)
        else:
            w, h = self.size_px_requested
            config.enable_stream(rs.stream.depth, w, h, rs.format.z16, self.fps)
            if self.with_image:
                config.enable_stream(rs.stream.infrared, 1, w, h, rs.format.y8, self.fps)
        pipeline = rs.pipeline()
        try:
            profile = pipeline.start(config)
        except RuntimeError as exc:
            where = self.bag if self.bag is not None else "no device"
            raise SourceError(f"RealSense ({where}): {exc}") from None
        self._pipeline = pipeline
        try:
            self._configure(rs, profile)
        except (RuntimeError, SourceError):
            self.close()
            raise

    def _configure(self, rs, profile) -> None:
        if self.bag is not None:
            playback = profile.get_device().as_playback()
            playback.set_real_time(False)
            stopped = rs.playback_status.stopped
            self._playback_stopped = lambda: playback.current_status() == stopped
        depth = profile.get_stream(rs.stream.depth).as_video_stream_profile()
        intr = depth.get_intrinsics()
        self.depth_scale_m = float(profile.get_device().first_depth_sensor().get_depth_scale())
        baseline_m = _baseline_m(rs, profile, self.baseline_override_m)
        self.intrinsics = StereoIntrinsics(
            int(intr.width),
            int(intr.height),
            float(intr.fx),
            float(intr.fy),
            float(intr.ppx),
            float(intr.ppy),
            baseline_m,
        )
        types = {(s.stream_type(), s.stream_index()) for s in profile.get_streams()}
        self._has_ir1 = self.with_image and (rs.stream.infrared, 1) in types
        what = f"bag:{self.bag}" if self.bag is not None else "device"
        self.description = (
            f"realsense:{what} ({intr.width}x{intr.height}, depth scale "
            f"{self.depth_scale_m:g} m, baseline {baseline_m * 1000:.1f} mm)"
        )

    def read(self) -> RawDepth | None:
        if self._pipeline is None or self._ended:
            return None
        start = time.monotonic()
        deadline = start + _LIVE_TIMEOUT_S
        while True:
            wait_ms = _WAIT_MS if self.bag is None else _POLL_MS
            ok, frames = self._pipeline.try_wait_for_frames(wait_ms)
            if not ok and self.bag is not None and self._playback_stopped():
                ok, frames = self._pipeline.try_wait_for_frames(_DRAIN_MS)
                if not ok:
                    self._ended = True  # the recording has ended
                    return None
            if not ok:
                if self.bag is not None:
                    if time.monotonic() - start >= _WAIT_MS / 1000:
                        self._ended = True  # nothing for that long: ended too
                        return None
                    continue
                if time.monotonic() >= deadline:
                    raise SourceError(f"RealSense: no frames for {_LIVE_TIMEOUT_S:g} s")
                continue
            depth = frames.get_depth_frame()
            if depth and depth.get_frame_number() != self._last_frame_number:
                break  # (a frameset may repeat the last depth frame beside a newer picture)
        self._last_frame_number = depth.get_frame_number()
        arrival_ns = self._clock()
        plane = np.array(np.asanyarray(depth.get_data()), dtype=np.uint16, copy=True)
        picture = None
        if self._has_ir1:
            ir = frames.get_infrared_frame(1)
            if ir and ir.get_timestamp() == depth.get_timestamp():  # the same exposure
                picture = np.array(np.asanyarray(ir.get_data()), dtype=np.uint8, copy=True)
                if picture.shape != plane.shape:
                    picture = None
        stamp_ns = round(depth.get_timestamp() * 1e6)
        units_m = float(depth.get_units())  # the frame's own units (the option may change)
        return RawDepth(
            plane,
            PixelEncoding.DEPTH16,
            units_m if math.isfinite(units_m) and units_m > 0 else self.depth_scale_m,
            picture,
            self._capture_ns(stamp_ns, arrival_ns),
        )

    def _capture_ns(self, stamp_ns: int, arrival_ns: int) -> int:
        """A device timestamp on the host's monotonic clock (module docstring)."""
        if self._replay is not None:
            return self._replay.capture_ns(stamp_ns)
        self._offsets.append(arrival_ns - stamp_ns)
        return stamp_ns + min(self._offsets)

    def close(self) -> None:
        if self._pipeline is not None:
            with contextlib.suppress(RuntimeError):
                self._pipeline.stop()
            self._pipeline = None
