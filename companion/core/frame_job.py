"""Frame step: a frame through the mission, and the latency budget (issue 32) it feeds.

A mixin of :class:`~companion.core.CompanionCore`. A frame whose capture time is
implausible, not newer than the last, or without a pose at its capture time is dropped
and counted; otherwise the :class:`~companion.core.mission.Mission` steps, its setpoint
goes out when the companion steers, and the status document follows. The data age of
each command (capture → on the wire, frame clock) feeds the latency budget.
"""

from __future__ import annotations

import dataclasses
import math

from companion.clock_model import FrameClock
from companion.core.events import FrameProcessed, Status
from companion.core.outbox import SEV_INFO, SEV_WARNING
from companion.link.setpoints import PositionTarget
from companion.pose_history import PoseStatus
from protocols.stereo_frame import StereoFrame

__all__ = ["FrameJob"]


class FrameJob:
    """One frame: pose at its capture time, the mission step, its setpoint and reports.

    Owns ``mission``, ``_last_capture_ns``, ``_newest_frame_ns``, ``data_age``,
    ``_age_pending``, ``_speed_limit_mps``, ``_boundaries``, ``_uncovered_told``.
    """

    def frame_time_plausible(self, capture_ns: int, now_ns: int) -> bool | None:
        """Capture time within the window around the clock model's now (any thread)."""
        window_ns = round(self.config.failsafe.frame_time_window_s * 1e9)
        return self.clock.frame_time_plausible(
            capture_ns, now_ns, self._telemetry_newest_ns, window_ns
        )

    def _on_frame(self, frame: StereoFrame, recv_ns: int) -> None:
        lookup = self._frame_pose(frame)
        if lookup is None:
            return
        assert lookup.pose is not None
        pose = dataclasses.replace(lookup.pose, h_acc_m=self._stated_h_acc_m(self._now_s))
        # Whether the vehicle flies what this frame yields (not in our failsafe hold, a
        # pilot's mode or beside another source): time it does not, guidance does not
        # count as its own lack of progress.
        steering = self._steering(self._now_s)
        age_s = self._frame_age_s(frame.capture_ns)
        try:
            result = self.mission.step(
                frame, pose, steering=steering, latency_s=self.data_age.budget_s(age_s)
            )
        except Exception as exc:  # a bad frame must never stop the companion (cv2.error too)
            self.counters.pipeline_errors += 1
            self.out.drop_log("pipeline", "frame %d: pipeline error %s", frame.sequence, exc)
            return
        out = result.output
        self._processed(frame.capture_ns, out, age_s, pose.pos_ned_m)
        self._check_failsafe(self._now_s)
        sent = False
        target = PositionTarget(tuple(float(x) for x in out.setpoint_ned_m), float(out.yaw_rad))
        if self._steering(self._now_s):
            assert self.policy is not None
            if self.policy.on_new_target(target, self._now_s):
                self._send_target(target, self._now_s, frame.capture_ns)
                sent = True
            self._state_speed_limit(out.envelope, self._now_s)
        self._check_overspeed(out)
        self._tell_uncovered(out.widening)
        self.counters.targets_kept_out += out.target_kept_out is not None
        self.counters.momentum_brakes += out.envelope.momentum_brake
        for notice in result.notices:
            self.out.notice(notice.text, SEV_WARNING if notice.warning else SEV_INFO)
        self.out.extend(result.events)
        self._send_proximity_frame(frame.capture_ns, pose)
        host_capture = frame.capture_ns if self.clock.frame_clock is FrameClock.HOST else None
        document = self._frame_status(result, lookup.status, pose, sent)
        self.out.append(Status(document, recv_ns, self._now_ns, host_capture))
        if self.report_pipeline:  # a viewer is attached (companion.viz)
            pipeline = self.mission.pipeline
            self.out.append(
                FrameProcessed(frame, pose, result, pipeline.goal_ned_m, pipeline.known_space, sent)
            )

    def _tell_uncovered(self, widened) -> None:
        """Say once per episode when the stated position accuracy exceeds what the margins
        take (:mod:`companion.position_uncertainty`)."""
        if widened.covered:
            self._uncovered_told = False
        elif not self._uncovered_told:
            self._uncovered_told = True
            self.out.notice(
                f"Position accuracy {widened.stated_m:.2f} m, margins cover "
                f"{widened.widen_m:.2f} m",
                SEV_WARNING,
            )

    def _frame_pose(self, frame: StereoFrame):
        """The pose lookup at the frame's capture time, or None: the frame is dropped
        (implausible time, during a takeoff, not newer than the last, no usable pose)."""
        if self.frame_time_plausible(frame.capture_ns, self._now_ns) is False:
            # frames never move the clock nor reset the mission: only telemetry may
            self.counters.frames_implausible_time += 1
            self._log_drop(
                "frames_implausible_time",
                self.counters.frames_implausible_time,
                "frame",
                (frame.sequence, frame.capture_ns),
            )
            return None
        if self.takeoff_job.busy:
            self._frame_during_takeoff(frame)
            return None
        if self._last_capture_ns is not None and frame.capture_ns <= self._last_capture_ns:
            self.counters.frames_stale += 1
            return None
        lookup = self.poses.at(frame.capture_ns)
        if not lookup.status.usable:
            self.out.drop_log(
                lookup.status.value,
                "frame %d dropped: no pose at its capture time (%s; %d so far)",
                frame.sequence,
                lookup.status.value,
                self.counters.pose_dropped(lookup.status),
            )
            return None
        if lookup.status is PoseStatus.EXTRAPOLATED:
            self.counters.pose_extrapolated += 1
        self._last_capture_ns = frame.capture_ns
        self._observe(frame.capture_ns)
        return lookup

    def _processed(self, capture_ns: int, out, age_s: float | None, pos_ned_m) -> None:
        """A frame went through the mission: health, its data age to take at the next
        input, the figures, and a hold target kept out of the boundaries it showed."""
        self.counters.frames_processed += 1
        self._newest_frame_ns = capture_ns
        self._age_pending = (capture_ns, self._now_ns, 0.0 if age_s is None else age_s)
        self._speed_limit_mps = float(out.envelope.speed_limit_mps)
        self._boundaries = tuple(out.boundaries)
        self._recheck_hold_target(pos_ned_m)

    def _frame_age_s(self, capture_ns: int) -> float | None:
        """Age of a frame's data now [s, frame clock] (None: no clock yet)."""
        now_frame = self.clock.now_frame_ns(self._now_ns, self._newest_seen_ns)
        return None if now_frame is None else (now_frame - capture_ns) * 1e-9

    def _frame_clock_rate(self) -> float:
        """Frame-clock seconds per host second (plant-sim at --speedup N: N)."""
        if self.clock.frame_clock is FrameClock.HOST:
            return 1.0
        rate = self.clock.autopilot.rate
        return min(max(rate, 0.01), 1000.0) if math.isfinite(rate) else 1.0

    def _measure_data_age(self) -> None:
        """The last frame's command left during its step: its data age is its age at the
        step's start plus the host time since then (this input's ``now_ns``, which the
        service steps right after carrying a frame's outputs out) on the frame clock."""
        if self._age_pending is None:
            return
        capture_ns, started_ns, age_at_start_s = self._age_pending
        self._age_pending = None
        compute_s = (self._now_ns - started_ns) * 1e-9 * self._frame_clock_rate()
        self.data_age.add(capture_ns, age_at_start_s + compute_s)

    def _frame_during_takeoff(self, frame: StereoFrame) -> None:
        """A frame while the takeoff runs: not steered on, it proves the camera works."""
        self._observe(frame.capture_ns)
        self.counters.frames_during_takeoff += 1  # not steering before the climb
        if self._newest_frame_ns is None or frame.capture_ns > self._newest_frame_ns:
            self._newest_frame_ns = frame.capture_ns  # the camera works: health
        self._engage(self.takeoff_job.on_frame(self._now_s), self._now_s)
