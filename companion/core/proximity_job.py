"""Proximity: OBSTACLE_DISTANCE from the known-space map, from start-up, in every mode.

A mixin of :class:`~companion.core.CompanionCore`. Sectors come from
:class:`~companion.proximity.sender.ProximitySender`: one message per processed frame,
stamped with its capture time, and a keep-alive between frames; both seen from where the
vehicle is at the send (:func:`~companion.proximity.sender.position_at_send`).
"""

from __future__ import annotations

from companion.link.messages import obstacle_distance_message
from companion.proximity.sender import position_at_send

__all__ = ["ProximityJob"]


class ProximityJob:
    """OBSTACLE_DISTANCE per frame and between frames.

    Owns ``proximity`` (None: turned off).
    """

    def _send_proximity_frame(self, capture_ns: int, pose) -> None:
        """OBSTACLE_DISTANCE of the map this frame updated, stamped with its capture time,
        seen from where the vehicle is now (not where it was when the frame was taken:
        the frame's processing time is not added to the autopilot's reaction)."""
        if self.proximity is None:
            return
        pos, yaw = self._proximity_pose()
        if pos is None and self.telemetry.position_host_ns is None:
            pos, yaw = pose.pos_ned_m, pose.yaw_rad  # no telemetry of its own yet
        sectors = self.proximity.on_frame(self.mission.pipeline.known_space, pos, yaw, self._now_s)
        self.out.send(obstacle_distance_message(capture_ns // 1000, sectors))

    def _send_proximity_now(self, now_s: float) -> None:
        """OBSTACLE_DISTANCE between frames: the map from where the vehicle is now (all
        unknown without a fresh position), stamped with the newest depth's capture time
        (frame clock)."""
        assert self.proximity is not None
        pos, yaw = self._proximity_pose()
        sectors = self.proximity.on_timer(self.mission.pipeline.known_space, pos, yaw, now_s)
        newest = self.poses.newest_ns
        last_capture_ns = self.frames.last_capture_ns
        stamp_ns = last_capture_ns if last_capture_ns is not None else newest
        self.out.send(obstacle_distance_message(max(stamp_ns or 0, 0) // 1000, sectors))

    def _proximity_pose(self):
        """(position [m, LOCAL_NED], yaw [rad]) of the vehicle at this send: the newest
        telemetry carried forward over the host time since its position arrived, on the
        frame clock's rate; (None, None) without one or when it is stale (counted)."""
        newest = self.poses.newest_ns
        if newest is None or self.telemetry.position_host_ns is None:
            return None, None
        pose = self.poses.at(newest).pose
        if pose is None:
            return None, None
        telemetry = self.telemetry
        age_s = (self._now_ns - telemetry.position_host_ns) * 1e-9 * telemetry.frame_clock_rate()
        pos = position_at_send(pose.pos_ned_m, pose.vel_ned_mps, age_s)
        if pos is None:
            self.proximity.stale_pose += 1
            return None, None
        return pos, pose.yaw_rad
