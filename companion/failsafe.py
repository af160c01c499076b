"""Failsafe decisions: stale frames or stale telemetry → hold; resume when healthy.

Pure. Ages are measured on the frame clock (:mod:`companion.clock_model`), which in the SIL
is the simulation time, so a run at ``--speedup`` 10 holds after the same simulated delay
as one at 1×. The caller turns a hold into BRAKE (ArduPilot) or a hold-position setpoint.

Hysteresis: a hold starts as soon as frames or telemetry are older than their timeout,
but ends only after they have been healthy for ``resume_after_s`` without a break, so one
late frame costs one hold, not a BRAKE/GUIDED flap at the frame rate.
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

    def __init__(
        self, frame_timeout_s: float, telemetry_timeout_s: float, resume_after_s: float = 0.0
    ) -> None:
        self.frame_timeout_s = frame_timeout_s
        self.telemetry_timeout_s = telemetry_timeout_s
        self.resume_after_s = resume_after_s
        self.status = FailsafeStatus(Health.NO_TELEMETRY, None, None)
        self.holds = 0
        self._was_healthy = False  # healthy at least once: later losses are holds
        self._healthy_since_ns: int | None = None

    def update(
        self, now_frame_ns: int | None, newest_frame_ns: int | None, newest_pose_ns: int | None
    ) -> Health | None:
        """New status; returns the new health when it changed, else None.

        After a loss of health, HEALTHY is reported only once :func:`assess` has said so
        for ``resume_after_s`` (frame clock) without a break; until then the status keeps
        the reason of the hold, with the current ages.
        """
        previous = self.status.health
        raw = assess(
            now_frame_ns,
            newest_frame_ns,
            newest_pose_ns,
            frame_timeout_s=self.frame_timeout_s,
            telemetry_timeout_s=self.telemetry_timeout_s,
        )
        if not raw.health.ok:
            self._healthy_since_ns = None
        elif not previous.ok and self._was_healthy and self.resume_after_s > 0:
            assert now_frame_ns is not None  # a healthy verdict needs a clock
            if self._healthy_since_ns is None or now_frame_ns < self._healthy_since_ns:
                self._healthy_since_ns = now_frame_ns
            if (now_frame_ns - self._healthy_since_ns) * 1e-9 < self.resume_after_s:
                self.status = FailsafeStatus(previous, raw.frame_age_s, raw.telemetry_age_s)
                return None
        self.status = raw
        if raw.health is previous:
            return None
        if previous.ok:
            self.holds += 1
        if raw.health.ok:
            self._was_healthy = True
            self._healthy_since_ns = None
        return raw.health
