"""Failsafe decisions: stale frames or stale telemetry → hold; resume when healthy.

Pure. Ages are measured on the frame clock (:mod:`companion.clock_model`), which in the SIL
is the simulation time, so a run at ``--speedup`` 10 holds after the same simulated delay
as one at 1×. The caller turns a hold into BRAKE (ArduPilot) or a hold-position setpoint.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

__all__ = ["FailsafeMonitor", "FailsafeStatus", "Health", "assess"]


class Health(enum.Enum):
    """Why the companion may or may not steer."""

    HEALTHY = "healthy"
    NO_CLOCK = "no_clock"  # the frame clock cannot be estimated yet (no TIMESYNC)
    NO_FRAMES = "no_frames"  # no frame processed yet
    STALE_FRAMES = "stale_frames"  # newest processed frame too old
    NO_TELEMETRY = "no_telemetry"  # no pose yet
    STALE_TELEMETRY = "stale_telemetry"  # newest pose too old

    @property
    def ok(self) -> bool:
        return self is Health.HEALTHY


@dataclass(frozen=True)
class FailsafeStatus:
    """A health verdict and the ages behind it [s on the frame clock] (None: unknown)."""

    health: Health
    frame_age_s: float | None
    telemetry_age_s: float | None


def assess(
    now_frame_ns: int | None,
    newest_frame_ns: int | None,
    newest_pose_ns: int | None,
    *,
    frame_timeout_s: float,
    telemetry_timeout_s: float,
) -> FailsafeStatus:
    """Health from the newest processed frame and pose, both on the frame clock."""
    if now_frame_ns is None:
        return FailsafeStatus(Health.NO_CLOCK, None, None)
    frame_age = None if newest_frame_ns is None else (now_frame_ns - newest_frame_ns) * 1e-9
    pose_age = None if newest_pose_ns is None else (now_frame_ns - newest_pose_ns) * 1e-9
    if pose_age is None:
        health = Health.NO_TELEMETRY
    elif pose_age > telemetry_timeout_s:
        health = Health.STALE_TELEMETRY
    elif frame_age is None:
        health = Health.NO_FRAMES
    elif frame_age > frame_timeout_s:
        health = Health.STALE_FRAMES
    else:
        health = Health.HEALTHY
    return FailsafeStatus(health, frame_age, pose_age)


class FailsafeMonitor:
    """Tracks transitions of :func:`assess` so that each is reported once."""

    def __init__(self, frame_timeout_s: float, telemetry_timeout_s: float) -> None:
        self.frame_timeout_s = frame_timeout_s
        self.telemetry_timeout_s = telemetry_timeout_s
        self.status = FailsafeStatus(Health.NO_TELEMETRY, None, None)
        self.holds = 0

    def update(
        self, now_frame_ns: int | None, newest_frame_ns: int | None, newest_pose_ns: int | None
    ) -> Health | None:
        """New status; returns the new health when it changed, else None."""
        previous = self.status.health
        self.status = assess(
            now_frame_ns,
            newest_frame_ns,
            newest_pose_ns,
            frame_timeout_s=self.frame_timeout_s,
            telemetry_timeout_s=self.telemetry_timeout_s,
        )
        if self.status.health is previous:
            return None
        if previous.ok:
            self.holds += 1
        return self.status.health
