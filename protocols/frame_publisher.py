"""The one camera-frame publisher: encode (protocols.stereo_frame) and put on a Zenoh key.

Used by plant-sim's synthetic camera, ``stereo-camera`` and the tests' frame feeders, so
every frame on the wire is made the same way. A failed put is counted and logged, never
raised: a camera must not stop for one lost frame.
"""

from __future__ import annotations

import logging

import numpy as np
import zenoh

from protocols.camera import StereoIntrinsics
from protocols.stereo_frame import Frame, StereoFrame, encode

__all__ = ["FramePublisher"]

_log = logging.getLogger("protocols.frames")


class FramePublisher:
    """Publishes stereo frames on ``key`` of an open ``session``.

    Parameters
    ----------
    session : zenoh.Session
    key : str
        ``stereo_avoid/<vehicle_id>/stereo`` (:func:`protocols.keys.stereo_key`).
    drop : bool
        Congestion control: True drops frames under congestion (live cameras: the newest
        frame matters), False blocks (replays that must deliver every pair).
    """

    def __init__(self, session: zenoh.Session, key: str, *, drop: bool = True) -> None:
        self.key = key
        self.publish_errors = 0
        self._publisher = session.declare_publisher(
            key,
            congestion_control=(
                zenoh.CongestionControl.DROP if drop else zenoh.CongestionControl.BLOCK
            ),
            priority=zenoh.Priority.DATA_HIGH,
        )

    @property
    def has_subscribers(self) -> bool:
        """A subscriber matches the key."""
        return self._publisher is not None and self._publisher.matching_status.matching

    def publish(
        self,
        sequence: int,
        capture_ns: int,
        intrinsics: StereoIntrinsics,
        left: np.ndarray,
        right: np.ndarray,
    ) -> bool:
        """Encode and put one stereo pair; False (counted, logged) if Zenoh refused it."""
        return self.publish_frame(StereoFrame(sequence, capture_ns, intrinsics, left, right))

    def publish_frame(self, frame: Frame) -> bool:
        """Encode and put one frame (a stereo pair or a depth frame); False (counted,
        logged) if Zenoh refused it."""
        payload = encode(frame)
        sequence = frame.sequence
        if self._publisher is None:
            return False
        try:
            self._publisher.put(payload)
        except zenoh.ZError as exc:
            self.publish_errors += 1
            _log.warning("frame %d not published on %s: %s", sequence, self.key, exc)
            return False
        return True

    def close(self) -> None:
        if self._publisher is not None:
            self._publisher.undeclare()
            self._publisher = None
