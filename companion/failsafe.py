"""Failsafe decisions: late inputs → hold position; lost inputs → hold mode; resume settled.

Pure. Ages are measured on the frame clock (:mod:`companion.clock_model`), which in the SIL
is the simulation time, so a run at ``--speedup`` 10 holds after the same simulated delay
as one at 1×. Two thresholds per input (issue 32: a slow companion must not flap modes):

* **Late** (``frame_timeout_s``, ``telemetry_timeout_s``): the newest processed frame or
  pose is older than that, but inputs still come. :attr:`Response.HOLD_POSITION`: the
  companion keeps the control mode (GUIDED / OFFBOARD) and sends a position target at the
  braking point (:mod:`companion.guidance.hold`), no mode request.
* **Lost** (``frame_loss_s``, ``telemetry_loss_s``, longer): nothing for that long, or the
  frame clock lost. :attr:`Response.HOLD_MODE`: the companion can no longer command
  safely and asks the autopilot for its own hold (BRAKE on ArduPilot, Hold = AUTO_LOITER
  on PX4). The last resort.

Hysteresis: a hold starts, or escalates from position to mode, as soon as the inputs are
that old, but ends only after they have been healthy for ``resume_after_s`` without a
break (the settle time): a late frame costs one hold, not a hold/steer flap at the frame
rate, and a mode hold is never stepped down to a position hold.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

__all__ = ["FailsafeMonitor", "FailsafeStatus", "Health", "Response", "assess"]


class Health(enum.Enum):
    """Why the companion may or may not steer."""

    HEALTHY = "healthy"
    NO_CLOCK = "no_clock"  # the frame clock cannot be estimated yet (no TIMESYNC)
    NO_FRAMES = "no_frames"  # no frame processed yet
    STALE_FRAMES = "stale_frames"  # newest processed frame older than frame_timeout_s
    FRAMES_LOST = "frames_lost"  # ... older than frame_loss_s
    NO_TELEMETRY = "no_telemetry"  # no pose yet
    STALE_TELEMETRY = "stale_telemetry"  # newest pose older than telemetry_timeout_s
    TELEMETRY_LOST = "telemetry_lost"  # ... older than telemetry_loss_s

    @property
    def ok(self) -> bool:
        return self is Health.HEALTHY

    @property
    def response(self) -> Response:
        """What the companion does about it (module docstring)."""
        if self is Health.HEALTHY:
            return Response.STEER
        if self in (Health.STALE_FRAMES, Health.STALE_TELEMETRY):
            return Response.HOLD_POSITION
        return Response.HOLD_MODE


class Response(enum.IntEnum):
    """The companion's answer to its inputs' health, in rising order of severity."""

    STEER = 0  # fly guidance's setpoints
    HOLD_POSITION = 1  # a position target at the braking point, in the control mode
    HOLD_MODE = 2  # the autopilot's own hold (ArduPilot BRAKE, PX4 Hold = AUTO_LOITER)


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
    frame_loss_s: float = math.inf,
    telemetry_loss_s: float = math.inf,
) -> FailsafeStatus:
    """Health from the newest processed frame and pose, both on the frame clock.

    Ages above the ``*_loss_s`` thresholds are lost inputs, above ``*_timeout_s`` late
    ones. A non-finite age (a corrupt stamp) counts as lost."""
    if now_frame_ns is None:
        return FailsafeStatus(Health.NO_CLOCK, None, None)
    frame_age = None if newest_frame_ns is None else (now_frame_ns - newest_frame_ns) * 1e-9
    pose_age = None if newest_pose_ns is None else (now_frame_ns - newest_pose_ns) * 1e-9
    if pose_age is None:
        health = Health.NO_TELEMETRY
    elif not pose_age <= telemetry_loss_s:  # NaN too
        health = Health.TELEMETRY_LOST
    elif frame_age is not None and not frame_age <= frame_loss_s:
        health = Health.FRAMES_LOST
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
    """Tracks :func:`assess` with the hysteresis of the module docstring; each change of
    the reported health is returned once.

    Parameters
    ----------
    frame_timeout_s, telemetry_timeout_s : float
        Late inputs: hold position [s, frame clock].
    resume_after_s : float
        Settle time: healthy this long without a break before a hold ends [s].
    frame_loss_s, telemetry_loss_s : float
        Lost inputs: hold mode, the last resort [s, frame clock] (default: never).
    """

    def __init__(
        self,
        frame_timeout_s: float,
        telemetry_timeout_s: float,
        resume_after_s: float = 0.0,
        *,
        frame_loss_s: float = math.inf,
        telemetry_loss_s: float = math.inf,
    ) -> None:
        self.frame_timeout_s = frame_timeout_s
        self.telemetry_timeout_s = telemetry_timeout_s
        self.resume_after_s = resume_after_s
        self.frame_loss_s = frame_loss_s
        self.telemetry_loss_s = telemetry_loss_s
        self.status = FailsafeStatus(Health.NO_TELEMETRY, None, None)
        self.holds = 0  # holds entered from steering
        self._was_healthy = False  # healthy at least once: later losses are holds
        self._healthy_since_ns: int | None = None

    @property
    def response(self) -> Response:
        """What the companion must do now (the reported health's response)."""
        return self.status.health.response

    def update(
        self, now_frame_ns: int | None, newest_frame_ns: int | None, newest_pose_ns: int | None
    ) -> Health | None:
        """New status; returns the new health when it changed, else None.

        After a loss of health, HEALTHY is reported only once :func:`assess` has said so
        for ``resume_after_s`` (frame clock) without a break; until then, and while the
        inputs are less bad than the hold's reason (a lost input back but late), the
        status keeps the reason of the hold, with the current ages.
        """
        previous = self.status.health
        raw = assess(
            now_frame_ns,
            newest_frame_ns,
            newest_pose_ns,
            frame_timeout_s=self.frame_timeout_s,
            telemetry_timeout_s=self.telemetry_timeout_s,
            frame_loss_s=self.frame_loss_s,
            telemetry_loss_s=self.telemetry_loss_s,
        )
        holding = not previous.ok and self._was_healthy
        if not raw.health.ok:
            self._healthy_since_ns = None
            if holding and raw.health.response < previous.response:
                self.status = FailsafeStatus(previous, raw.frame_age_s, raw.telemetry_age_s)
                return None
        elif holding and self.resume_after_s > 0:
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
