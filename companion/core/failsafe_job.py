"""Failsafe: late inputs hold position, lost inputs ask for the autopilot's hold mode.

A component of :class:`~companion.core.CompanionCore` that owns its state: the health
monitor (:class:`~companion.failsafe.FailsafeMonitor`, frame clock, with its hysteresis),
the hold the companion commands and its target (latched at the hold's start: the braking
point, never inside a boundary, :func:`companion.guidance.hold.hold_point`), and whether
a moved target was said. Typed in: the frame clock's now and the newest frame and pose
stamps, whether the autopilot is known and a guidance setpoint was sent, and a
:class:`HoldView` (the newest pose, the boundaries, the latency budget) to place targets
from. Out: the :class:`~companion.failsafe.Response` to start or end (the core asks the
modes job for the autopilot's hold mode, BRAKE / PX4's Hold, as the last resort), hold
targets, and its notices and events in the step's :class:`~companion.core.outbox.Outbox`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

from companion.config import CompanionConfig
from companion.core.counters import CoreCounters
from companion.core.outbox import SEV_WARNING, Outbox
from companion.failsafe import FailsafeMonitor, FailsafeStatus, Health, Response
from companion.guidance.hold import HoldPlacement, WayCheck, hold_point, inside_any
from companion.link.setpoints import PositionTarget
from companion.pipeline import PoseAtCapture

_log = logging.getLogger("companion")

__all__ = ["FailsafeJob", "HoldView"]


#: what a hold that stays where the vehicle is says, by why it stays
_HELD_WHERE_IT_IS = {
    HoldPlacement.CURRENT: (
        "Hold target: no way out of a boundary within reach, holding where it is"
    ),
    HoldPlacement.UNSEEN: "Hold target: no way out of a boundary seen free, holding where it is",
}


@dataclass(frozen=True)
class HoldView:
    """What a hold target is placed from."""

    pose: PoseAtCapture | None  # the newest pose (None: none)
    boundaries: tuple  # the last processed frame's collision safety boundaries
    latency_s: float  # the latency budget now [s]
    # the map's question for a way out of a boundary (companion.guidance.hold.WayCheck;
    # None: ways out unchecked)
    way_check: WayCheck | None = None


class FailsafeJob:
    """Holds for late and lost inputs, their targets, and the resume.

    Parameters
    ----------
    config : CompanionConfig
        ``failsafe`` (timeouts, settle time), ``envelope.accel_mps2`` (braking) and
        ``guidance.escape_clearance_m`` (a target moved out of a boundary).
    out : Outbox
        Where notices and events go (the core's, per step).
    counters : CoreCounters
        ``hold_commands``, ``mode_holds``, ``hold_targets_moved``.
    """

    def __init__(self, config: CompanionConfig, out: Outbox, counters: CoreCounters) -> None:
        self._config = config
        self._out = out
        self._counters = counters
        self.reset()

    def reset(self) -> None:
        """Link lost or autopilot restarted: healthy again only once shown, no hold."""
        fs = self._config.failsafe
        self.monitor = FailsafeMonitor(
            fs.frame_timeout_s,
            fs.telemetry_timeout_s,
            fs.resume_after_s,
            frame_loss_s=fs.frame_loss_s,
            telemetry_loss_s=fs.telemetry_loss_s,
        )
        self.hold = Response.STEER  # the hold the companion commands
        self.hold_target: PositionTarget | None = None  # latched at a hold's start
        self._moved_told = False  # "hold target moved out of a boundary" said

    @property
    def status(self) -> FailsafeStatus:
        """Health (with the hold's reason while held) and the input ages."""
        return self.monitor.status

    def update(
        self,
        now_frame_ns: int | None,
        newest_frame_ns: int | None,
        newest_pose_ns: int | None,
        *,
        autopilot_known: bool,
        engaged: bool,
    ) -> Response | None:
        """The health now; the hold to start (HOLD_POSITION, HOLD_MODE), STEER to end
        the hold, or None (nothing to do: unchanged, a lesser response while in a
        stronger hold, or nothing steered yet to hold)."""
        changed = self.monitor.update(now_frame_ns, newest_frame_ns, newest_pose_ns)
        if not autopilot_known:
            return None  # (during a takeoff the health is tracked for the status only)
        response = self.monitor.response
        if response is self.hold or Response.STEER < response < self.hold:
            return None
        if response is Response.STEER:
            return response
        if not engaged or self.status.health in (Health.NO_FRAMES, Health.NO_CLOCK):
            if changed is not None:
                _log.info("not steering yet: %s", changed.value)
            return None
        return response

    def start_hold(self, response: Response, view: HoldView) -> None:
        """Hold (``response``): counted when a hold starts; its target latched."""
        if self.hold is Response.STEER:
            self._counters.hold_commands += 1
            self._moved_told = False
            self.hold_target = None
        self.hold = response
        self.hold_target = self.hold_target or self.hold_point_target(view)
        if response is Response.HOLD_MODE:
            self._counters.mode_holds += 1

    def report_hold(self, what: str, now_frame_ns: int | None, newest_frame_ns: int | None):
        """Say the hold started (STATUSTEXT, log, event); ``what``: its command."""
        status = self.status
        ages = f"frames {_age(status.frame_age_s)}, telemetry {_age(status.telemetry_age_s)}"
        self._out.notice(f"Failsafe {status.health.value}: {what}", SEV_WARNING)
        _log.warning("failsafe %s (%s): commanding %s", status.health.value, ages, what)
        target = self.hold_target
        self._out.event(
            "hold",
            reason=status.health.value,
            command=what,
            frame_age_s=status.frame_age_s,
            telemetry_age_s=status.telemetry_age_s,
            newest_frame_ns=newest_frame_ns,
            now_frame_ns=now_frame_ns,
            setpoint_ned_m=None if target is None else [round(x, 3) for x in target.pos_ned_m],
        )

    def end_hold(self) -> bool:
        """Healthy for the settle time: no hold; True (and said) if one was on."""
        was = self.hold
        self.hold, self.hold_target = Response.STEER, None
        if was is Response.STEER:
            return False
        self._out.notice("Frames and telemetry healthy: avoidance resumes")
        self._out.event("resume")
        return True

    def current_hold(self, view: HoldView) -> PositionTarget | None:
        """Hold where the vehicle is (out of a boundary it is in), no braking point."""
        return self.hold_point_target(view, moving=False)

    def hold_point_target(self, view: HoldView, *, moving: bool = True) -> PositionTarget | None:
        """The braking point of the newest pose, never inside a boundary
        (:func:`companion.guidance.hold.hold_point`); says so once per hold if moved."""
        pose = view.pose
        if pose is None:
            return None
        point = hold_point(
            pose.pos_ned_m,
            pose.vel_ned_mps if moving else (0.0, 0.0, 0.0),
            view.boundaries,
            latency_s=view.latency_s,
            accel_mps2=self._config.envelope.accel_mps2,
            clearance_m=self._config.guidance.escape_clearance_m,
            way_check=view.way_check,
        )
        if point.moved and not self._moved_told:
            self._moved_told = True
            self._counters.hold_targets_moved += 1
            self._out.notice(
                _HELD_WHERE_IT_IS.get(
                    point.placement, f"Hold target kept out of a boundary ({point.placement.value})"
                )
            )
            self._out.event(
                "hold_target_moved",
                placement=point.placement.value,
                setpoint_ned_m=[round(x, 3) for x in point.pos_ned_m],
                pos_ned_m=[round(float(x), 3) for x in pose.pos_ned_m],
            )
        look = point.look_yaw_rad  # facing a way out the camera must look along first
        return PositionTarget(point.pos_ned_m, pose.yaw_rad if look is None else look)

    def recheck_target(self, pos_ned_m, view: HoldView) -> PositionTarget | None:
        """In a position hold, a frame that shows the vehicle or its target inside a
        boundary (drift, a late frame) moves the target out: the new target to send."""
        if self.hold is not Response.HOLD_POSITION or self.hold_target is None:
            return None
        if not (
            inside_any(pos_ned_m, view.boundaries)
            or inside_any(self.hold_target.pos_ned_m, view.boundaries)
        ):
            return None
        target = self.hold_point_target(view)
        if target is None or target == self.hold_target:
            return None
        self.hold_target = target
        return target


def _age(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f} s"
