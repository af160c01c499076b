"""Proximity: OBSTACLE_DISTANCE from the known-space map, from start-up, in every mode.

A component of :class:`~companion.core.CompanionCore` around the
:class:`~companion.proximity.sender.ProximitySender` (None: turned off), which owns the
state: one message per processed frame, stamped with its capture time, and a keep-alive
between frames; both seen from where the vehicle is at the send
(:func:`~companion.proximity.sender.position_at_send`). Typed in: the known-space map, the
newest pose and the age of its position, the frame's pose and stamps. Out:
OBSTACLE_DISTANCE in the step's :class:`~companion.core.outbox.Outbox`.
"""

from __future__ import annotations

from companion.core.outbox import Outbox
from companion.link.messages import obstacle_distance_message
from companion.pipeline import PoseAtCapture
from companion.proximity.sender import ProximitySender, position_at_send

__all__ = ["ProximityJob"]


class ProximityJob:
    """OBSTACLE_DISTANCE per frame and between frames.

    Parameters
    ----------
    sender : ProximitySender or None
        The sectors and their pacing (None: turned off).
    out : Outbox
        Where OBSTACLE_DISTANCE goes (the core's, per step).
    """

    def __init__(self, sender: ProximitySender | None, out: Outbox) -> None:
        self.sender = sender
        self._out = out

    def due(self, now_s: float) -> bool:
        """A keep-alive between frames is due."""
        return self.sender is not None and self.sender.due(now_s)

    def on_frame(
        self, capture_ns: int, space, pose_now, fallback: PoseAtCapture | None, now_s: float
    ) -> None:
        """OBSTACLE_DISTANCE of the map this frame updated, stamped with its capture time,
        seen from where the vehicle is now (``pose_now``: :meth:`pose_at_send`; not where
        it was when the frame was taken: the frame's processing time is not added to the
        autopilot's reaction); from ``fallback``, the frame's pose, when there is no
        telemetry of its own yet (None: there is)."""
        if self.sender is None:
            return
        pos, yaw = pose_now
        if pos is None and fallback is not None:
            pos, yaw = fallback.pos_ned_m, fallback.yaw_rad
        sectors = self.sender.on_frame(space, pos, yaw, now_s)
        self._out.send(obstacle_distance_message(capture_ns // 1000, sectors))

    def on_timer(self, space, pose_now, stamp_ns: int | None, now_s: float) -> None:
        """OBSTACLE_DISTANCE between frames: the map from where the vehicle is now (all
        unknown without a fresh position), stamped ``stamp_ns`` (the newest depth's
        capture time, frame clock)."""
        assert self.sender is not None
        pos, yaw = pose_now
        sectors = self.sender.on_timer(space, pos, yaw, now_s)
        self._out.send(obstacle_distance_message(max(stamp_ns or 0, 0) // 1000, sectors))

    def pose_at_send(self, pose: PoseAtCapture | None, position_age_s: float | None):
        """(position [m, LOCAL_NED], yaw [rad]) of the vehicle at this send: the newest
        telemetry ``pose`` carried forward over its position's age [s, frame clock];
        (None, None) without one or when it is stale (counted)."""
        if pose is None or position_age_s is None:
            return None, None
        pos = position_at_send(pose.pos_ned_m, pose.vel_ned_mps, position_age_s)
        if pos is None:
            assert self.sender is not None
            self.sender.stale_pose += 1
            return None, None
        return pos, pose.yaw_rad
