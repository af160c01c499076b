"""The companion core's counters: one typed record instead of counters named by strings.

Every field counts events since the core was built (link losses and autopilot restarts do
not reset it); :meth:`CoreCounters.as_dict` gives them, in declaration order, for the exit
statistics and the status.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from companion.pose_history import PoseStatus

__all__ = ["CoreCounters"]


@dataclass(slots=True)
class CoreCounters:
    """What the core did and dropped (counts)."""

    frames_processed: int = 0  # frames through the mission
    frames_stale: int = 0  # not newer than the last processed frame
    pose_empty: int = 0  # frame dropped: no pose yet
    pose_too_old: int = 0  # frame dropped: older than the pose history
    pose_too_new: int = 0  # frame dropped: newer than the newest pose + extrapolation
    pose_extrapolated: int = 0  # frame's pose extrapolated (used)
    telemetry_unmapped: int = 0  # telemetry before the clock could map it
    setpoints_sent: int = 0
    hold_commands: int = 0  # failsafe holds entered from steering
    link_losses: int = 0
    autopilot_restarts: int = 0
    mode_releases: int = 0  # a pilot or ground station took the mode
    mode_requests: int = 0  # DO_SET_MODE sent (engage, hold, release, retries)
    mode_holds: int = 0  # holds that asked for the autopilot's hold mode
    hold_targets_moved: int = 0  # hold targets kept out of a boundary
    targets_kept_out: int = 0  # frames whose carrot was kept out of a boundary (invariant 3)
    momentum_brakes: int = 0  # frames braked: the way to the carrot not seen free (envelope step 8)
    pipeline_errors: int = 0
    speed_limits_sent: int = 0
    speed_limits_accepted: int = 0
    speed_limits_refused: int = 0
    overspeed_frames: int = 0
    frames_during_takeoff: int = 0
    frames_implausible_time: int = 0
    telemetry_implausible_time: int = 0
    telemetry_out_of_range: int = 0
    timesync_unmatched: int = 0
    handler_errors: int = 0
    takeover_refusals: int = 0
    mavlink_sent: int = 0

    def pose_dropped(self, status: PoseStatus) -> int:
        """Count a frame dropped for an unusable pose lookup; returns the new count."""
        if status is PoseStatus.EMPTY:
            self.pose_empty += 1
            return self.pose_empty
        if status is PoseStatus.TOO_OLD:
            self.pose_too_old += 1
            return self.pose_too_old
        if status is PoseStatus.TOO_NEW:
            self.pose_too_new += 1
            return self.pose_too_new
        raise ValueError(f"pose lookup {status.value} is usable, not a drop")

    def as_dict(self) -> dict[str, int]:
        """Every counter by name, in declaration order."""
        return dataclasses.asdict(self)
