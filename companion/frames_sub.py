"""Camera frames (stereo pairs or depth frames) from Zenoh into a latest-value slot (never a
growing queue).

The Zenoh callback decodes each payload (:func:`protocols.stereo_frame.decode` validates
every header field and the byte count) and puts the frame in a :class:`LatestFrameSlot`,
replacing one the service has not taken yet (counted as superseded). Malformed payloads
are counted and logged, at most one log line per ``log_period_s``. The slot has a wake-up
file descriptor so the service can ``select`` on frames and MAVLink at once.

Sessions use explicit endpoints with multicast scouting off, or a Zenoh config file
(routers, TLS, access control) to which explicit endpoints are added.
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import zenoh

from protocols.keys import ALL_STEREO_KEYS, vehicle_of_stereo_key
from protocols.stereo_frame import Frame, FrameDecodeError, decode

__all__ = ["FrameCounters", "FrameSubscriber", "LatestFrameSlot", "PublisherProbe"]

_log = logging.getLogger("companion.frames")


@dataclass
class FrameCounters:
    """Frames seen by the subscriber."""

    received: int = 0  # payloads delivered by Zenoh
    decoded: int = 0  # valid frames
    malformed: int = 0  # refused by the decoder
    superseded: int = 0  # replaced by a newer frame before the service took them
    taken: int = 0  # handed to the service
    implausible_time: int = 0  # capture time outside the clock's window: refused at intake
    no_clock: int = 0  # arrived before telemetry gave the clock a "now": dropped


class LatestFrameSlot:
    """Holds only the newest frame; ``take()`` empties it. Thread-safe, with a wake-up fd."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._frame: Frame | None = None
        self._rfd, self._wfd = os.pipe()
        os.set_blocking(self._rfd, False)
        os.set_blocking(self._wfd, False)
        self._signalled = False
        self.counters = FrameCounters()

    def fileno(self) -> int:
        return self._rfd

    def put(self, frame: Frame) -> None:
        with self._lock:
            if self._frame is not None:
                self.counters.superseded += 1
            self._frame = frame
            if not self._signalled:
                self._signalled = True
                with contextlib.suppress(BlockingIOError):
                    os.write(self._wfd, b"\x01")

    def take(self) -> Frame | None:
        with self._lock:
            frame, self._frame = self._frame, None
            if self._signalled:
                self._signalled = False
                with contextlib.suppress(BlockingIOError):
                    os.read(self._rfd, 64)
            if frame is not None:
                self.counters.taken += 1
            return frame

    def close(self) -> None:
        for fd in (self._rfd, self._wfd):
            with contextlib.suppress(OSError):
                os.close(fd)


class FrameSubscriber:
    """Declares the Zenoh subscriber on ``key`` and feeds ``slot``.

    ``accept_capture_ns`` (optional, called on Zenoh's thread: True, False, or None when
    there is no clock yet) refuses frames whose capture time is implausible before they
    reach the slot, so a hostile stream cannot evict the
    genuine newest frame; refusals are counted and logged like malformed payloads.
    """

    def __init__(
        self,
        session: zenoh.Session,
        key: str,
        slot: LatestFrameSlot,
        log_period_s: float = 2.0,
        accept_capture_ns: Callable[[int], bool | None] | None = None,
    ) -> None:
        self.key = key
        self.slot = slot
        self._accept = accept_capture_ns
        self._session = session
        self._sub = None
        self._log_period_s = log_period_s
        self._last_log_s = -float("inf")
        self._unlogged = 0
        self._count_lock = threading.Lock()
        self._kind: tuple | None = None  # (encoding, width, height) of the last frame

    def open(self) -> None:
        self._sub = self._session.declare_subscriber(self.key, self._on_sample)

    def close(self) -> None:
        if self._sub is not None:
            self._sub.undeclare()
            self._sub = None

    def _on_sample(self, sample) -> None:
        c = self.slot.counters
        try:
            payload = sample.payload.to_bytes()
        except (ValueError, TypeError, zenoh.ZError) as exc:
            self._malformed(f"unreadable payload: {exc}")
            return
        with self._count_lock:
            c.received += 1
        try:
            frame = decode(payload)
        except FrameDecodeError as exc:
            self._malformed(str(exc))
            return
        with self._count_lock:
            c.decoded += 1
        self._note_kind(frame)
        verdict = True if self._accept is None else self._accept(frame.capture_ns)
        if verdict is None:
            with self._count_lock:
                c.no_clock += 1  # no telemetry yet to place it: not an attack, not logged
            return
        if not verdict:
            with self._count_lock:
                c.implausible_time += 1
            self._malformed(
                f"capture time {frame.capture_ns} ns outside the clock window", count=False
            )
            return
        self.slot.put(frame)

    def _note_kind(self, frame) -> None:
        """Log what the camera sends when it starts or changes: the encoding picks the
        depth source (a depth camera's frames run no matcher)."""
        k = frame.intrinsics
        kind = (frame.encoding, k.width_px, k.height_px)
        if kind == self._kind:
            return
        self._kind = kind
        what = "depth camera, no matcher" if frame.encoding.is_depth else "stereo pair, matcher"
        _log.info("frames on %s: %s %dx%d (%s)", self.key, frame.encoding.name, *kind[1:], what)

    def _malformed(self, reason: str, *, count: bool = True) -> None:
        with self._count_lock:
            if count:
                self.slot.counters.malformed += 1
            self._unlogged += 1
            now = time.monotonic()
            if now - self._last_log_s < self._log_period_s:
                return
            self._last_log_s = now
            n, self._unlogged = self._unlogged, 0
            total = self.slot.counters.malformed
        _log.warning(
            "dropped %d frame payload(s) on %s (malformed in total: %d), latest: %s",
            n,
            self.key,
            total,
            reason,
        )


class PublisherProbe:
    """Which vehicle ids publish stereo frames, while ours has none (a wrong ``--vehicle-id``).

    Subscribes to every vehicle's stereo key and records the vehicle ids seen (payloads are
    not decoded). Declared only while the companion gets no frames on its own key, so it
    costs nothing in normal operation; :meth:`close` undeclares it.
    """

    def __init__(self, session: zenoh.Session) -> None:
        self._session = session
        self._sub = None
        self._lock = threading.Lock()
        self._seen: set[str] = set()

    @property
    def active(self) -> bool:
        return self._sub is not None

    def open(self) -> None:
        if self._sub is None:
            self._sub = self._session.declare_subscriber(ALL_STEREO_KEYS, self._on_sample)

    def _on_sample(self, sample) -> None:
        vehicle = vehicle_of_stereo_key(str(sample.key_expr))
        if vehicle is not None:
            with self._lock:
                self._seen.add(vehicle)

    def vehicles(self) -> list[str]:
        with self._lock:
            return sorted(self._seen)

    def close(self) -> None:
        if self._sub is not None:
            self._sub.undeclare()
            self._sub = None
