"""Companion guidance (paper §5, Fig. 5): collision cone, aiming point, mode switching.

Pure code, no I/O or clocks: boundary spheres (NED, inflated) and the vehicle state in,
a mode, the avoidance flag of Fig. 11, a position setpoint and a yaw out.

* :mod:`~companion.guidance.cone` — cone geometry, Eq. (28), the head-on tie-break.
* :mod:`~companion.guidance.planner` — aiming point among several obstacles, or none.
* :mod:`~companion.guidance.memory` — obstacles remembered out of the field of view.
* :mod:`~companion.guidance.map_boundaries` — the boundary spheres cut from the
  known-space map (several bounded pieces per extended obstacle).
* :mod:`~companion.guidance.avoidance` — NAVIGATE / AVOID / HOLD with hysteresis.
* :mod:`~companion.guidance.config` — the tuning, one frozen dataclass.
* :mod:`~companion.guidance.envelope` — the safety envelope: the carrot inside known-free
  space (:mod:`companion.known_space`) and the stopping-distance speed limit.
"""

from companion.guidance.avoidance import (
    Guidance,
    GuidanceOutput,
    GuidanceState,
    Mode,
    Reason,
    guidance_step,
)
from companion.guidance.cone import (
    BoundarySphere,
    CollisionCone,
    SphereLike,
    aiming_direction,
    aiming_point,
    collision_cone,
    contains_direction,
    escape_point,
    is_critical,
    segment_intersects_sphere,
    side_step_direction,
    tangent_circle_points,
)
from companion.guidance.config import GuidanceConfig, UnknownGuidanceKeyError
from companion.guidance.memory import ObstacleMemory, TrackedObstacle, update_memory
from companion.guidance.planner import AimChoice, choose_aiming_point, overlapping_cluster

__all__ = [
    "AimChoice",
    "BoundarySphere",
    "CollisionCone",
    "Guidance",
    "GuidanceConfig",
    "GuidanceOutput",
    "GuidanceState",
    "Mode",
    "ObstacleMemory",
    "Reason",
    "SphereLike",
    "TrackedObstacle",
    "UnknownGuidanceKeyError",
    "aiming_direction",
    "aiming_point",
    "choose_aiming_point",
    "collision_cone",
    "contains_direction",
    "escape_point",
    "guidance_step",
    "is_critical",
    "overlapping_cluster",
    "segment_intersects_sphere",
    "side_step_direction",
    "tangent_circle_points",
    "update_memory",
]
