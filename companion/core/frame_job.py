"""Frame step: a frame through the mission, and the latency budget (issue 32) it feeds.

A component of :class:`~companion.core.CompanionCore` that owns its state: the
:class:`~companion.core.mission.Mission` (waypoints around the avoidance pipeline), the
capture times of the last admitted and processed frames, the last frame's boundaries and
speed limit, the data-age window of the latency budget, and the notice of uncovered
position accuracy. Typed in: a frame with the pose lookup at its capture time (a frame
not newer than the last, or without a usable pose, is dropped and counted), whether the
vehicle flies what it yields, and the frame's data age. Out: the
:class:`~companion.core.mission.MissionStep` (None: the pipeline failed, counted), its
notices and events in the step's :class:`~companion.core.outbox.Outbox`. The data age of
each command (capture → on the wire, frame clock) is taken at the next input.
"""

from __future__ import annotations

from companion.config import CompanionConfig
from companion.core.counters import CoreCounters
from companion.core.mission import Mission, MissionStep
from companion.core.outbox import SEV_INFO, SEV_WARNING, Outbox
from companion.guidance.latency import DataAgeWindow
from companion.phase_times import PhaseTimes
from companion.pipeline import PoseAtCapture
from companion.pose_history import PoseLookup, PoseStatus
from protocols.stereo_frame import StereoFrame

__all__ = ["FrameJob"]


class FrameJob:
    """One frame: admitted, the mission stepped, its reports; the latency budget.

    Parameters
    ----------
    config : CompanionConfig
        Waypoints, goal tolerance, perception, guidance, known space, envelope.
    out : Outbox
        Where the mission's notices and events go (the core's, per step).
    counters : CoreCounters
        ``frames_*``, ``pose_*``, ``pipeline_errors``, ``targets_kept_out``.
    phases : PhaseTimes, optional
        Where every mission's pipeline counts (and times) its phases; kept across resets.
    """

    def __init__(
        self,
        config: CompanionConfig,
        out: Outbox,
        counters: CoreCounters,
        phases: PhaseTimes | None = None,
    ) -> None:
        self._config = config
        self._out = out
        self._counters = counters
        self.phases = PhaseTimes() if phases is None else phases
        self.reset()

    def reset(self) -> None:
        """Link lost or autopilot restarted: a new mission, nothing measured."""
        cfg = self._config
        self.mission = Mission(
            cfg.waypoints_ned_m,
            cfg.goal_tolerance_m,
            cfg.perception,
            cfg.guidance,
            cfg.known_space,
            cfg.envelope,
        )
        self.mission.pipeline.phases = self.phases
        self.boundaries: tuple = ()  # the last processed frame's boundaries
        self.newest_frame_ns: int | None = None  # processed (or proving the camera)
        self.last_capture_ns: int | None = None  # admitted
        env = cfg.envelope
        self.data_age = DataAgeWindow(
            env.latency_s, env.latency_window_s, env.latency_percentile, env.unmeasured_latency_s
        )
        # the frame whose command left in the last step: (capture_ns, host ns at the
        # step's start, its data age then [s]); its age is taken at the next input
        self._age_pending: tuple[int, int, float] | None = None
        self.speed_limit_mps: float | None = None  # the envelope's, last processed frame
        self._uncovered_told = False  # the margins' widening notice

    def admit(self, frame: StereoFrame, lookup: PoseLookup) -> bool:
        """The frame goes through (True), or is dropped: not newer than the last, or no
        usable pose at its capture time (counted, logged every 2 s)."""
        if self.last_capture_ns is not None and frame.capture_ns <= self.last_capture_ns:
            self._counters.frames_stale += 1
            return False
        if not lookup.status.usable:
            self._out.drop_log(
                lookup.status.value,
                "frame %d dropped: no pose at its capture time (%s; %d so far)",
                frame.sequence,
                lookup.status.value,
                self._counters.pose_dropped(lookup.status),
            )
            return False
        if lookup.status is PoseStatus.EXTRAPOLATED:
            self._counters.pose_extrapolated += 1
        self.last_capture_ns = frame.capture_ns
        return True

    def during_takeoff(self, capture_ns: int) -> None:
        """A frame while the takeoff runs: not steered on, it proves the camera works."""
        self._counters.frames_during_takeoff += 1  # not steering before the climb
        if self.newest_frame_ns is None or capture_ns > self.newest_frame_ns:
            self.newest_frame_ns = capture_ns  # the camera works: health

    def step(
        self,
        frame: StereoFrame,
        pose: PoseAtCapture,
        steering: bool,
        age_s: float | None,
        guide: bool = True,
    ) -> MissionStep | None:
        """The mission on this frame (``age_s``: its data age now, None: no clock yet;
        ``guide`` False: the companion is not in control, guidance does not run); None
        when the pipeline failed (counted: a bad frame never stops the companion)."""
        try:
            return self.mission.step(
                frame,
                pose,
                steering=steering,
                latency_s=self.data_age.budget_s(age_s),
                guide=guide,
            )
        except Exception as exc:  # cv2.error too
            self._counters.pipeline_errors += 1
            self._out.drop_log("pipeline", "frame %d: pipeline error %s", frame.sequence, exc)
            return None

    def processed(self, capture_ns: int, result: MissionStep, age_s, now_ns: int) -> None:
        """A frame went through the mission at host time ``now_ns``: its data age to take
        at the next input, its boundaries and speed limit kept."""
        out = result.output
        self._counters.frames_processed += 1
        self.newest_frame_ns = capture_ns
        self._age_pending = (capture_ns, now_ns, 0.0 if age_s is None else age_s)
        # not guided: no bound was stated (the status says "-")
        self.speed_limit_mps = float(out.envelope.speed_limit_mps) if out.guided else None
        self.boundaries = tuple(out.boundaries)

    def report(self, result: MissionStep) -> None:
        """The step's reports: uncovered accuracy (once per episode), targets kept out of
        a boundary (counted), the mission's notices and events."""
        out = result.output
        self._tell_uncovered(out.widening)
        self._counters.targets_kept_out += out.target_kept_out is not None
        self._counters.momentum_brakes += out.envelope.momentum_brake
        for notice in result.notices:
            self._out.notice(notice.text, SEV_WARNING if notice.warning else SEV_INFO)
        self._out.extend(result.events)

    def measure_data_age(self, now_ns: int, frame_clock_rate: float) -> None:
        """The last frame's command left during its step: its data age is its age at the
        step's start plus the host time since then (this input's ``now_ns``, which the
        service steps right after carrying a frame's outputs out) on the frame clock."""
        if self._age_pending is None:
            return
        capture_ns, started_ns, age_at_start_s = self._age_pending
        self._age_pending = None
        compute_s = (now_ns - started_ns) * 1e-9 * frame_clock_rate
        self.data_age.add(capture_ns, age_at_start_s + compute_s)

    def _tell_uncovered(self, widened) -> None:
        """Say once per episode when the stated position accuracy exceeds what the margins
        take (:mod:`companion.position_uncertainty`)."""
        if widened.covered:
            self._uncovered_told = False
        elif not self._uncovered_told:
            self._uncovered_told = True
            self._out.notice(
                f"Position accuracy {widened.stated_m:.2f} m, margins cover "
                f"{widened.widen_m:.2f} m",
                SEV_WARNING,
            )
