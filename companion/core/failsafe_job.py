"""Failsafe: late inputs hold position, lost inputs ask for the autopilot's hold mode.

A mixin of :class:`~companion.core.CompanionCore`. Health and hysteresis are
:class:`~companion.failsafe.FailsafeMonitor`'s (frame clock); this job commands the hold
(a position target at the braking point, never inside a boundary; BRAKE / PX4's Hold as
the last resort) and resumes after the settle time.
"""

from __future__ import annotations

import logging

from companion.config import CompanionConfig
from companion.core.outbox import SEV_WARNING
from companion.failsafe import FailsafeMonitor, Health, Response
from companion.guidance.hold import HoldPlacement, hold_point, inside_any
from companion.link.setpoints import PositionTarget

_log = logging.getLogger("companion")

__all__ = ["FailsafeJob", "failsafe_monitor"]


class FailsafeJob:
    """Holds for late and lost inputs, their targets, and the resume.

    Owns ``failsafe``, ``_hold``, ``_hold_target``, ``_hold_moved_told``.
    """

    def _check_failsafe(self, now_s: float) -> None:
        """Late inputs: a position hold in the control mode; lost inputs: the autopilot's
        hold mode (the last resort); healthy for the settle time: steer again."""
        now_frame = self.telemetry.now_frame_ns(self._now_ns)
        changed = self.failsafe.update(now_frame, self._newest_frame_ns, self.poses.newest_ns)
        if self.modes.flavour is None:
            return  # (during a takeoff the health is tracked for the status line only)
        response = self.failsafe.response
        if response is self._hold or Response.STEER < response < self._hold:
            return
        if response is Response.STEER:
            self._end_hold(now_s)
            return
        status = self.failsafe.status
        if not self._engaged or status.health in (Health.NO_FRAMES, Health.NO_CLOCK):
            if changed is not None:
                _log.info("not steering yet: %s", changed.value)
            return
        before = self.modes.phase
        if self._hold is Response.STEER:
            self.counters.hold_commands += 1
            self._hold_moved_told = False
            self._hold_target = None
        self._hold = response
        self._hold_target = self._hold_target or self._hold_point_target()
        request = None
        if response is Response.HOLD_MODE:
            self.counters.mode_holds += 1
            request = self.modes.set_hold(now_s, True)
        what = request.name if request is not None else "hold position"
        ages = f"frames {_age(status.frame_age_s)}, telemetry {_age(status.telemetry_age_s)}"
        self.out.notice(f"Failsafe {status.health.value}: {what}", SEV_WARNING)
        _log.warning("failsafe %s (%s): commanding %s", status.health.value, ages, what)
        self.out.event(
            "hold",
            reason=status.health.value,
            command=what,
            frame_age_s=status.frame_age_s,
            telemetry_age_s=status.telemetry_age_s,
            newest_frame_ns=self._newest_frame_ns,
            now_frame_ns=now_frame,
            setpoint_ned_m=None
            if self._hold_target is None
            else [round(x, 3) for x in self._hold_target.pos_ned_m],
        )
        if request is not None:
            self.modes.request(request)
        else:
            self._resend_now(now_s)
        self._after_phase_change(self.modes.changed(before), now_s)

    def _end_hold(self, now_s: float) -> None:
        """Healthy for the settle time: guidance's setpoints again (the control mode)."""
        before, was = self.modes.phase, self._hold
        self._hold, self._hold_target = Response.STEER, None
        request = self.modes.set_hold(now_s, False)
        if was is not Response.STEER:
            self.out.notice("Frames and telemetry healthy: avoidance resumes")
            self.out.event("resume")
            if self.policy is not None:
                self.policy.reset()  # the next guidance setpoint goes out at once
        if request is not None:
            self.modes.request(request)
        self._after_phase_change(self.modes.changed(before), now_s)

    def _current_hold(self) -> PositionTarget | None:
        """Hold where the vehicle is (out of a boundary it is in), no braking point."""
        return self._hold_point_target(moving=False)

    def _hold_point_target(self, *, moving: bool = True) -> PositionTarget | None:
        """The braking point of the newest pose, never inside a boundary
        (:func:`companion.guidance.hold.hold_point`); says so once per hold if moved."""
        newest = self.poses.newest_ns
        if newest is None:
            return None
        lookup = self.poses.at(newest)
        if lookup.pose is None:
            return None
        pose = lookup.pose
        point = hold_point(
            pose.pos_ned_m,
            pose.vel_ned_mps if moving else (0.0, 0.0, 0.0),
            self._boundaries,
            latency_s=self.data_age.budget_s(),
            accel_mps2=self.config.envelope.accel_mps2,
            clearance_m=self.config.guidance.escape_clearance_m,
        )
        if point.moved and not self._hold_moved_told:
            self._hold_moved_told = True
            self.counters.hold_targets_moved += 1
            self.out.notice(
                "Hold target: no way out of a boundary within reach, holding where it is"
                if point.placement is HoldPlacement.CURRENT
                else f"Hold target kept out of a boundary ({point.placement.value})"
            )
            self.out.event(
                "hold_target_moved",
                placement=point.placement.value,
                setpoint_ned_m=[round(x, 3) for x in point.pos_ned_m],
                pos_ned_m=[round(float(x), 3) for x in pose.pos_ned_m],
            )
        return PositionTarget(point.pos_ned_m, pose.yaw_rad)

    def _recheck_hold_target(self, pos_ned_m) -> None:
        """In a position hold, a frame that shows the vehicle or its target inside a
        boundary (drift, a late frame) moves the target out at once."""
        if self._hold is not Response.HOLD_POSITION or self._hold_target is None:
            return
        if not (
            inside_any(pos_ned_m, self._boundaries)
            or inside_any(self._hold_target.pos_ned_m, self._boundaries)
        ):
            return
        target = self._hold_point_target()
        if target is not None and target != self._hold_target:
            self._hold_target = target
            if self.modes.steering and self.policy is not None and self._may_steer(self._now_s):
                self._send_target(target, self._now_s, None)


def failsafe_monitor(config: CompanionConfig) -> FailsafeMonitor:
    fs = config.failsafe
    return FailsafeMonitor(
        fs.frame_timeout_s,
        fs.telemetry_timeout_s,
        fs.resume_after_s,
        frame_loss_s=fs.frame_loss_s,
        telemetry_loss_s=fs.telemetry_loss_s,
    )


def _age(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f} s"
