"""Proximity: OBSTACLE_DISTANCE from the known-space map, from start-up, in every mode.

A mixin of :class:`~companion.core.CompanionCore`. Sectors come from
:class:`~companion.proximity.sender.ProximitySender`: one message per processed frame,
stamped with its capture time, and a keep-alive between frames.
"""

from __future__ import annotations

from companion.link.messages import obstacle_distance_message

__all__ = ["ProximityJob"]


class ProximityJob:
    """OBSTACLE_DISTANCE per frame and between frames.

    Owns ``proximity`` (None: turned off).
    """

    def _send_proximity_frame(self, capture_ns: int, pose) -> None:
        """OBSTACLE_DISTANCE of the map this frame updated, stamped with its capture time,
        seen from the newest telemetry pose (where the vehicle is now, not where it was
        when the frame was taken: the frame's processing time is not added to the
        autopilot's reaction) or, without a newer one, from the frame's pose."""
        if self.proximity is None:
            return
        newest = self.poses.newest_ns
        if newest is not None and newest > capture_ns:
            lookup = self.poses.at(newest)
            if lookup.pose is not None:
                pose = lookup.pose
        sectors = self.proximity.on_frame(
            self.mission.pipeline.known_space, pose.pos_ned_m, pose.yaw_rad, self._now_s
        )
        self.out.send(obstacle_distance_message(capture_ns // 1000, sectors))

    def _send_proximity_now(self, now_s: float) -> None:
        """OBSTACLE_DISTANCE between frames: the map at the newest pose (all unknown
        without one), stamped with the newest depth's capture time (frame clock)."""
        assert self.proximity is not None
        pose = None
        newest = self.poses.newest_ns
        if newest is not None:
            pose = self.poses.at(newest).pose
        sectors = self.proximity.on_timer(
            self.mission.pipeline.known_space,
            None if pose is None else pose.pos_ned_m,
            None if pose is None else pose.yaw_rad,
            now_s,
        )
        stamp_ns = self._last_capture_ns if self._last_capture_ns is not None else newest
        self.out.send(obstacle_distance_message(max(stamp_ns or 0, 0) // 1000, sectors))
