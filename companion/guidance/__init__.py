"""Companion guidance (paper §5, Fig. 5): collision cone, aiming point, mode switching.

Pure code, no I/O or clocks: boundary spheres (NED, inflated) and the vehicle state in,
a mode, the avoidance flag of Fig. 11, a position setpoint and a yaw out.

* :mod:`~companion.guidance.cone` — cone geometry, Eq. (28), the head-on tie-break.
* :mod:`~companion.guidance.planner` — aiming point among several obstacles, or none.
* :mod:`~companion.guidance.memory` — obstacles remembered out of the field of view.
* :mod:`~companion.guidance.map_boundaries` — the boundary spheres cut from the
  known-space map (several bounded pieces per extended obstacle); made smaller where they
  would close an opening seen free (:mod:`~companion.guidance.openings`).
* :mod:`~companion.guidance.avoidance` — NAVIGATE / AVOID / HOLD with hysteresis (the
  step); its :mod:`~companion.guidance.modes`, :mod:`~companion.guidance.step_types`
  (state and output), :mod:`~companion.guidance.goal_stop` (the stop short of an
  unreachable goal) and :mod:`~companion.guidance.progress` (every stall reported).
* :mod:`~companion.guidance.go_look` — one bounded look, from a side no surface hides it,
  at a goal held only by a blind spot, before the stop short of it stands.
* :mod:`~companion.guidance.config` — the tuning, one frozen dataclass.
* :mod:`~companion.guidance.envelope` — the safety envelope: the carrot inside known-free
  space (:mod:`companion.known_space`) and the stopping-distance speed limit.
* :mod:`~companion.guidance.known_path` — a path through space seen free (A* over the
  known-space map), flown where the cone rule finds no way or closes one the map shows.

The public API is the step and its types; the geometry and planning functions are
public in their own modules (``companion.guidance.cone`` etc.) for tests and tools.

* :class:`Guidance` / :func:`guidance_step` — one perception frame in, a
  :class:`GuidanceOutput` (mode, :class:`Reason`, avoidance flag, setpoint, yaw) out; the
  state between frames is a :class:`GuidanceState`.
* :class:`GuidanceConfig` — the tuning (unknown keys: :class:`UnknownGuidanceKeyError`).
* :class:`BoundarySphere` / :class:`SphereLike` — what perception hands in;
  :class:`TrackedObstacle` — what the memory keeps.
"""

from companion.guidance.avoidance import (
    Guidance,
    GuidanceOutput,
    GuidanceState,
    Mode,
    Reason,
    guidance_step,
)
from companion.guidance.cone import BoundarySphere, SphereLike
from companion.guidance.config import GuidanceConfig, UnknownGuidanceKeyError
from companion.guidance.memory import TrackedObstacle

__all__ = [
    "BoundarySphere",
    "Guidance",
    "GuidanceConfig",
    "GuidanceOutput",
    "GuidanceState",
    "Mode",
    "Reason",
    "SphereLike",
    "TrackedObstacle",
    "UnknownGuidanceKeyError",
    "guidance_step",
]
