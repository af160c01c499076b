"""Waypoint mission around the avoidance pipeline: frame + pose in, command and reports out.

The part of the companion that both the networked core and the lockstep harness run per
frame: advance to the next waypoint once the current one is within ``goal_tolerance_m``,
run :class:`~companion.pipeline.AvoidancePipeline` toward the current waypoint, and report
what changed (goal reached, hold entered, avoidance started or ended). Pure: no clocks,
no I/O; times are the frames' capture times.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from companion.core.events import Event, MissionStep, Notice
from companion.depth_source import DepthSource
from companion.guidance import GuidanceConfig, Mode, Reason
from companion.guidance.envelope import EnvelopeConfig
from companion.guidance.hold import HoldPlacement
from companion.guidance.tracking import TrackingMonitor
from companion.known_space import KnownSpaceConfig
from companion.perception import PerceptionConfig
from companion.pipeline import AvoidancePipeline, PipelineOutput, PoseAtCapture
from protocols.stereo_frame import StereoFrame

__all__ = ["Mission", "MissionStep", "Notice"]

#: a carrot kept out of a boundary is said again only after this long without one [s]
_KEPT_OUT_QUIET_S = 5.0


class Mission:
    """Fly ``waypoints_ned_m`` in order with the avoidance pipeline (one call per frame).

    Parameters
    ----------
    waypoints_ned_m : sequence of 3-sequences
        LOCAL_NED [m]; the last one is the goal.
    goal_tolerance_m : float
        A waypoint counts as reached within this distance [m].
    perception, guidance, known_space, envelope : configs of the pipeline.
    depth_source : DepthSource, optional
        The pipeline's depth source for stereo pairs (default: the matcher).
    """

    def __init__(
        self,
        waypoints_ned_m: Sequence[Sequence[float]],
        goal_tolerance_m: float,
        perception: PerceptionConfig | None = None,
        guidance: GuidanceConfig | None = None,
        known_space: KnownSpaceConfig | None = None,
        envelope: EnvelopeConfig | None = None,
        *,
        depth_source: DepthSource | None = None,
    ) -> None:
        if not waypoints_ned_m:
            raise ValueError("a mission needs at least one waypoint")
        if not (math.isfinite(goal_tolerance_m) and goal_tolerance_m > 0):
            raise ValueError(f"goal_tolerance_m must be > 0, got {goal_tolerance_m!r}")
        self.waypoints_ned_m = tuple(tuple(float(x) for x in wp) for wp in waypoints_ned_m)
        self.goal_tolerance_m = float(goal_tolerance_m)
        self.pipeline = AvoidancePipeline(
            self.waypoints_ned_m[0],
            perception,
            guidance,
            known_space,
            envelope,
            depth_source=depth_source,
        )
        self.waypoint = 0
        self.goal_reached = False
        self._guidance_state: tuple[Mode, Reason] | None = None
        self._avoiding = False
        self._hold_escaped = False  # this hold already said its target was moved out
        self._look_ned_m = None  # the viewpoint of a look at the goal said last, or None
        self._kept_out_until_s = -math.inf  # a carrot kept out of a boundary was said until
        self._momentum_until_s = -math.inf  # a momentum brake was said until
        self.tracking = TrackingMonitor(self.pipeline.envelope_config.margin_m)
        self._flown_target: np.ndarray | None = None  # the previous frame's command

    @property
    def target_ned_m(self) -> np.ndarray:
        """The waypoint being flown to [m, NED]."""
        return self.pipeline.goal_ned_m

    @property
    def on_last_waypoint(self) -> bool:
        return self.waypoint + 1 >= len(self.waypoints_ned_m)

    def step(
        self,
        frame: StereoFrame,
        pose: PoseAtCapture,
        *,
        steering: bool = True,
        latency_s: float | None = None,
        guide: bool = True,
    ) -> MissionStep:
        """Run one frame; ``pose`` is the vehicle's at ``frame.capture_ns``; ``steering``
        says whether the vehicle flies the output (:meth:`Pipeline.process`); ``latency_s``
        is the latency budget [s] the caller measured (the data age of recent commands,
        :class:`~companion.guidance.latency.DataAgeWindow`; None: the configured floor, as
        in lockstep, where a frame's setpoint acts at its capture time); ``guide`` False:
        the companion is not in control, guidance does not run
        (:meth:`AvoidancePipeline.process`) and its changes are not reported.

        Raises whatever the pipeline raises on a bad frame (the caller counts and drops
        it); the mission's state is unchanged by a frame that raised, except for a
        waypoint reached before it.
        """
        notices: list[Notice] = []
        events: list[Event] = []
        self._advance_waypoint(pose.pos_ned_m, notices)
        out = self.pipeline.process(
            frame, pose, steering=steering, latency_s=latency_s, guide=guide
        )
        self._check_goal(pose.pos_ned_m, frame.capture_ns, notices, events)
        if out.guided:
            self._report_changes(out, frame.capture_ns, notices, events)
        self._check_tracking(pose, frame.capture_ns, notices, events)
        self._report_kept_out(out, frame.capture_ns, notices, events)
        self._report_look(out, frame.capture_ns, notices, events)
        self._report_momentum(out, frame.capture_ns, notices, events)
        self._flown_target = np.array(out.setpoint_ned_m) if steering else None
        return MissionStep(out, self.waypoint, tuple(notices), tuple(events))

    def _check_tracking(self, pose: PoseAtCapture, capture_ns: int, notices, events) -> None:
        """Say once when the vehicle rests farther from its target than the margin."""
        report = self.tracking.update(
            capture_ns * 1e-9, pose.pos_ned_m, pose.vel_ned_mps, self._flown_target
        )
        if report is None:
            return
        notices.append(
            Notice(
                f"Holding {report.offset_m:.2f} m off target (wind?): margin "
                f"{report.margin_m:.2f} m not kept",
                warning=True,
            )
        )
        events.append(
            Event(
                "tracking_offset",
                {
                    "offset_m": round(report.offset_m, 3),
                    "margin_m": report.margin_m,
                    "target_ned_m": list(report.target_ned_m),
                    "capture_s": capture_ns * 1e-9,
                },
            )
        )

    def _report_kept_out(self, out: PipelineOutput, capture_ns: int, notices, events) -> None:
        """Say once per episode (quiet for ``_KEPT_OUT_QUIET_S`` between) that a carrot was
        kept out of a boundary (invariant 3, :func:`~companion.guidance.hold.keep_target_out`;
        the core counts every such frame)."""
        if out.target_kept_out is None:
            return
        now_s = capture_ns * 1e-9
        quiet = now_s >= self._kept_out_until_s
        self._kept_out_until_s = now_s + _KEPT_OUT_QUIET_S
        if not quiet:
            return
        placement = out.target_kept_out.value
        text = (
            "Inside a boundary, no way out seen free: holding where it is"
            if out.target_kept_out is HoldPlacement.UNSEEN
            else f"Target kept out of a boundary ({placement})"
        )
        notices.append(Notice(text, warning=True))
        events.append(
            Event(
                "target_kept_out",
                {
                    "placement": placement,
                    "setpoint_ned_m": [float(x) for x in out.setpoint_ned_m],
                    "capture_s": now_s,
                },
            )
        )

    def _report_momentum(self, out: PipelineOutput, capture_ns: int, notices, events) -> None:
        """Say once per episode (quiet for ``_KEPT_OUT_QUIET_S`` between) that the envelope
        braked because the way the autopilot would fly to the carrot was not seen free
        (step 8 of :mod:`companion.guidance.envelope`; the core counts every such frame)."""
        env = out.envelope
        if not env.momentum_brake:
            return
        now_s = capture_ns * 1e-9
        quiet = now_s >= self._momentum_until_s
        self._momentum_until_s = now_s + _KEPT_OUT_QUIET_S
        if not quiet:
            return
        notices.append(Notice(f"Braking: way to target not seen free at {env.speed_mps:.1f} m/s"))
        events.append(
            Event(
                "momentum_brake",
                {
                    "speed_mps": round(env.speed_mps, 3),
                    "speed_limit_mps": round(env.speed_limit_mps, 3),
                    "free_distance_m": round(env.free_distance_m, 3),
                    "guidance_setpoint_ned_m": [float(x) for x in out.guidance.setpoint_ned_m],
                    "capture_s": now_s,
                },
            )
        )

    def _advance_waypoint(self, pos_ned_m: np.ndarray, notices: list[Notice]) -> None:
        if self.on_last_waypoint:
            return
        if float(np.linalg.norm(pos_ned_m - self.target_ned_m)) < self.goal_tolerance_m:
            self.waypoint += 1
            self.pipeline.goal_ned_m = np.array(self.waypoints_ned_m[self.waypoint])
            notices.append(Notice(f"Waypoint {self.waypoint} of {len(self.waypoints_ned_m) - 1}"))

    def _check_goal(self, pos_ned_m, capture_ns: int, notices: list, events: list) -> None:
        if self.goal_reached or not self.on_last_waypoint:
            return
        distance_m = float(np.linalg.norm(pos_ned_m - self.target_ned_m))
        if distance_m < self.goal_tolerance_m:
            self.goal_reached = True
            notices.append(Notice("Goal reached"))
            events.append(
                Event("goal_reached", {"capture_s": capture_ns * 1e-9, "distance_m": distance_m})
            )

    def _report_changes(self, out: PipelineOutput, capture_ns: int, notices, events) -> None:
        g = out.guidance
        if (g.mode, g.reason) != self._guidance_state:
            was_holding = self._guidance_state is not None and self._guidance_state[0] is Mode.HOLD
            self._guidance_state = (g.mode, g.reason)
            if g.mode is Mode.HOLD:
                sp = out.setpoint_ned_m
                notices.append(
                    Notice(
                        f"Holding ({g.reason.value}) at N{sp[0]:.1f} E{sp[1]:.1f} D{sp[2]:.1f}",
                        warning=True,
                    )
                )
                events.append(
                    Event(
                        "hold",
                        {
                            "reason": g.reason.value,
                            "setpoint_ned_m": [float(x) for x in sp],
                            "capture_s": capture_ns * 1e-9,
                        },
                    )
                )
            elif was_holding:
                events.append(
                    Event("hold_end", {"reason": g.reason.value, "capture_s": capture_ns * 1e-9})
                )
        if out.hold_escape and not self._hold_escaped:
            # said once per hold (not every frame it is re-checked)
            notices.append(Notice("Hold target kept out of a boundary (escape)", warning=True))
            sp = out.setpoint_ned_m
            events.append(
                Event(
                    "hold_target_moved",
                    {
                        "placement": "escape",
                        "setpoint_ned_m": [float(x) for x in sp],
                        "capture_s": capture_ns * 1e-9,
                    },
                )
            )
        self._hold_escaped = (self._hold_escaped or out.hold_escape) and g.mode is Mode.HOLD
        if g.avoidance_flag != self._avoiding:
            self._avoiding = bool(g.avoidance_flag)
            events.append(
                Event("avoidance", {"active": self._avoiding, "capture_s": capture_ns * 1e-9})
            )
            if self._avoiding:
                near = min((o.nearest_m for o in out.obstacles), default=math.nan)
                where = f" at {near:.1f} m" if math.isfinite(near) else " (remembered)"
                notices.append(Notice(f"Avoiding obstacle{where}", warning=True))
            else:
                notices.append(Notice("Avoidance ended, heading to goal"))

    def _report_look(self, out: PipelineOutput, capture_ns: int, notices, events) -> None:
        """Say when a look at a goal held only by a blind spot starts and ends
        (:mod:`companion.guidance.go_look`): after "Holding (goal_unreachable)" the
        vehicle moves on, and the pilot hears why."""
        look = out.look_ned_m
        if look == self._look_ned_m:
            return
        self._look_ned_m = look
        if look is not None:
            notices.append(
                Notice(
                    f"Looking at goal from N{look[0]:.1f} E{look[1]:.1f} (blind spot)",
                    warning=True,
                )
            )
        events.append(
            Event(
                "goal_look",
                {
                    "viewpoint_ned_m": None if look is None else [float(x) for x in look],
                    "capture_s": capture_ns * 1e-9,
                },
            )
        )
