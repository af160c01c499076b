"""Status: the state in the heartbeat, the pipeline figures, the progress line and stats.

A component of :class:`~companion.core.CompanionCore` that owns no state: it reads the
other components (read-only: telemetry, modes, failsafe, frames, setpoints, takeoff and
the OBSTACLE_DISTANCE sender) and the counters. The state itself is a pure function of a
typed view (:func:`companion_state`); out: the state, the status document of a processed
frame, the progress line and the exit statistics.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from companion.core.counters import CoreCounters
from companion.core.failsafe_job import FailsafeJob
from companion.core.frame_job import FrameJob
from companion.core.modes_job import ModesJob
from companion.core.setpoint_job import SetpointJob
from companion.core.takeoff_job import TakeoffJob
from companion.core.telemetry_job import TelemetryJob
from companion.failsafe import Response
from companion.link.flavour import mode_name
from companion.link.messages import CompanionState
from companion.link.mode_watch import ControlPhase
from companion.proximity.sender import ProximitySender
from companion.status import status_document

__all__ = ["StateView", "StatusJob", "companion_state"]


@dataclass(frozen=True)
class StateView:
    """What the companion's state is decided from (:func:`companion_state`)."""

    link_up: bool  # an autopilot message within the link timeout
    link_lost_before: bool  # the link was lost at least once
    may_steer: bool  # alone on the link and heard long enough
    phase: ControlPhase
    hold: Response  # the hold the failsafe commands (STEER: none)
    steering: bool  # the mode watch lets guidance steer
    health_ok: bool  # frames and telemetry fresh
    frame_processed: bool  # a frame went through the pipeline (or proved the camera)


def companion_state(view: StateView) -> CompanionState:
    """The state in the heartbeat and the status: BOOT until the link and a frame, LINK_LOST
    after a loss, STANDBY when it may not or does not steer, HOLD in a hold, ACTIVE."""
    if not view.link_up:
        return CompanionState.LINK_LOST if view.link_lost_before else CompanionState.BOOT
    if not view.may_steer:
        return CompanionState.STANDBY
    if view.phase is ControlPhase.HOLD or view.hold is not Response.STEER:
        return CompanionState.HOLD
    if view.steering and view.health_ok:
        return CompanionState.ACTIVE
    if not view.frame_processed:
        return CompanionState.BOOT
    return CompanionState.STANDBY


class StatusJob:
    """The companion's state, figures, progress line and exit statistics.

    Parameters
    ----------
    counters : CoreCounters
    telemetry, modes, failsafe, frames, setpoints, takeoff
        The core's components, read here only.
    proximity : ProximitySender or None
        The OBSTACLE_DISTANCE sender (None: turned off).
    """

    def __init__(
        self,
        counters: CoreCounters,
        telemetry: TelemetryJob,
        modes: ModesJob,
        failsafe: FailsafeJob,
        frames: FrameJob,
        setpoints: SetpointJob,
        takeoff: TakeoffJob,
        proximity: ProximitySender | None,
    ) -> None:
        self.counters = counters
        self.telemetry = telemetry
        self.modes = modes
        self.failsafe = failsafe
        self.frames = frames
        self.setpoints = setpoints
        self.takeoff_job = takeoff
        self.proximity = proximity

    def state(self, link_up: bool, may_steer: bool) -> CompanionState:
        """The companion's state (:func:`companion_state`) with the link's figures."""
        return companion_state(
            StateView(
                link_up=link_up,
                link_lost_before=self.counters.link_losses > 0,
                may_steer=may_steer,
                phase=self.modes.phase,
                hold=self.failsafe.hold,
                steering=self.modes.steering,
                health_ok=self.failsafe.status.health.ok,
                frame_processed=self.frames.newest_frame_ns is not None,
            )
        )

    def stats(self) -> dict[str, Any]:
        """Counters and state for the exit statistics."""
        policy = self.setpoints.policy  # made from the autopilot's first heartbeat
        takeoff = self.takeoff_job.sequence
        return {
            **self.counters.as_dict(),
            "phase": self.modes.phase.value,
            "flavour": None if policy is None else policy.flavour.value,
            "clock_rate": round(self.telemetry.clock.autopilot.rate, 3),
            "waypoint": self.frames.mission.waypoint,
            "takeoff": None if takeoff is None else takeoff.step.value,
            "obstacle_distance_sent": None if self.proximity is None else self.proximity.sent,
            "obstacle_distance_late": None if self.proximity is None else self.proximity.late,
        }

    def progress_text(self, now_s: float) -> str:
        """One line for the periodic progress log (time, position, phase, mode, health)."""
        poses = self.telemetry.poses
        newest = poses.newest_ns
        pos = "-"
        if newest is not None:
            lookup = poses.at(newest)
            if lookup.pose is not None:
                p = lookup.pose.pos_ned_m
                pos = f"({p[0]:.1f}, {p[1]:.1f}, {p[2]:.1f})"
        mode = self.modes.mode_text()
        takeoff = self.takeoff_job.sequence
        if takeoff is not None and takeoff.busy and takeoff.custom_mode is not None:
            mode = mode_name(takeoff.flavour, takeoff.custom_mode)
        phase = (
            f"takeoff:{takeoff.step.value}"
            if takeoff is not None and takeoff.busy
            else self.modes.phase.value
        )
        return (
            f"t={'-' if newest is None else f'{newest * 1e-9:.1f}s'} pos={pos} phase={phase} "
            f"mode={mode} health={self.failsafe.status.health.value} "
            f"frames {self.counters.frames_processed} setpoints "
            f"{self.counters.setpoints_sent}; {self._pipeline_text(now_s)}"
        )

    def _pipeline_text(self, now_s: float) -> str:
        """Rate, data age p50/p99, latency budget, speed limit and mode requests."""
        f = self.pipeline_figures()

        def num(value, fmt: str) -> str:
            return "-" if value is None else format(value, fmt)

        return (
            f"processing {num(f['rate_hz'], '.1f')} Hz, data age p50 "
            f"{num(f['data_age_p50_ms'], '.0f')} p99 {num(f['data_age_p99_ms'], '.0f')} ms, "
            f"latency budget {f['latency_budget_s']:.2f} s, speed limit "
            f"{num(f['speed_limit_mps'], '.1f')} m/s, mode requests "
            f"{self.counters.mode_requests}{self._proximity_text(now_s)}"
        )

    def _proximity_text(self, now_s: float) -> str:
        if self.proximity is None:
            return ", OBSTACLE_DISTANCE off"
        p = self.proximity.figures(now_s)
        return (
            f", OBSTACLE_DISTANCE {p['sent']} at {p['rate_hz']:.1f} Hz (sectors: "
            f"{p['obstacle_sectors']} obstacle, {p['clear_sectors']} clear, "
            f"{p['unknown_sectors']} unknown)"
            + (f", {p['late']} sent past the 0.5 s timeout" if p["late"] else "")
        )

    def frame_status(
        self, result, pose_status, pose, sent: bool, state: CompanionState, now_s: float
    ) -> dict[str, Any]:
        """The status document of a processed frame (:func:`companion.status.status_document`)."""
        out = result.output
        return status_document(
            out,
            state=state.value,
            phase=self.modes.phase.value,
            autopilot_mode=self.modes.mode_text(),
            health=self.failsafe.status.health.value,
            pose=pose_status.value,
            pos_ned_m=[round(float(x), 4) for x in pose.pos_ned_m],
            waypoint=result.waypoint,
            setpoint_sent=sent,
            pipeline=self.pipeline_figures(out.envelope.latency_s),
            mode_requests=self.counters.mode_requests,
            proximity=None if self.proximity is None else self.proximity.figures(now_s),
            guided=out.guided,  # False: not in control, guidance and the envelope skipped
        )

    def pipeline_figures(self, latency_s: float | None = None) -> dict[str, Any]:
        """Processing rate, data age p50/p99, latency budget and speed limit (status)."""
        stats = self.frames.data_age.stats()

        def ms(value: float | None) -> float | None:
            return None if value is None else round(value * 1e3, 1)

        return {
            "rate_hz": None if stats.rate_hz is None else round(stats.rate_hz, 2),
            "data_age_p50_ms": ms(stats.p50_s),
            "data_age_p99_ms": ms(stats.p99_s),
            "latency_budget_s": round(
                self.frames.data_age.budget_s() if latency_s is None else latency_s, 4
            ),
            "speed_limit_mps": None
            if self.frames.speed_limit_mps is None
            else round(self.frames.speed_limit_mps, 3),
            "ages_rejected": self.frames.data_age.rejected,
            "ages_clamped": self.frames.data_age.clamped,
        }
