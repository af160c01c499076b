"""The companion's pure avoidance pipeline: stereo frame + pose at capture → setpoint.

One call per frame: perception (disparity → depth → boundary spheres in NED, paper §4–5)
then guidance (collision cone, aiming point, mode switching, Fig. 5). No sockets, files or
clocks: the networked service and the lockstep harness both run exactly this.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from companion.guidance import Guidance, GuidanceConfig, GuidanceOutput
from companion.perception import PerceptionConfig, PerceptionResult, StereoPerception
from protocols.stereo_frame import StereoFrame

__all__ = ["AvoidancePipeline", "PipelineOutput", "PoseAtCapture"]


@dataclass(frozen=True, eq=False)
class PoseAtCapture:
    """The vehicle's pose and velocity at a frame's capture time (LOCAL_NED, FRD)."""

    pos_ned_m: np.ndarray
    vel_ned_mps: np.ndarray
    R_ned_from_frd: np.ndarray


@dataclass(frozen=True, eq=False)
class PipelineOutput:
    """What one frame produced: the obstacles seen and the guidance decision."""

    perception: PerceptionResult
    guidance: GuidanceOutput


class AvoidancePipeline:
    """Perception + guidance toward one goal (Fig. 5), stepped once per stereo frame.

    Parameters
    ----------
    goal_ned_m : sequence of 3 float
        Where to go, LOCAL_NED [m].
    perception, guidance : configs (defaults: the paper's 4 m threshold etc.).
    """

    def __init__(
        self,
        goal_ned_m,
        perception: PerceptionConfig | None = None,
        guidance: GuidanceConfig | None = None,
    ) -> None:
        goal = np.array(goal_ned_m, dtype=float)
        if goal.shape != (3,) or not np.all(np.isfinite(goal)):
            raise ValueError(f"goal_ned_m must be 3 finite numbers, got {goal_ned_m!r}")
        self.goal_ned_m = goal
        self.perception = StereoPerception(perception)
        self.guidance = Guidance(guidance)

    def process(self, frame: StereoFrame, pose: PoseAtCapture) -> PipelineOutput:
        """Run one frame; ``pose`` must be the vehicle's at ``frame.capture_ns``."""
        seen = self.perception.process(frame, pose.pos_ned_m, pose.R_ned_from_frd)
        decision = self.guidance.step(
            time_s=frame.capture_ns * 1e-9,
            pos_ned_m=pose.pos_ned_m,
            vel_ned_mps=pose.vel_ned_mps,
            goal_ned_m=self.goal_ned_m,
            detections=seen.obstacles,
        )
        return PipelineOutput(perception=seen, guidance=decision)
