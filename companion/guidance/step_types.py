"""What guidance keeps between frames and what one step decides (the state threaded
through :func:`companion.guidance.avoidance.guidance_step`, and its output)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from companion.guidance.memory import ObstacleMemory, TrackedObstacle
from companion.guidance.modes import Mode, Reason
from companion.guidance.progress import Progress

__all__ = ["GuidanceOutput", "GuidanceState"]


@dataclass(frozen=True)
class GuidanceState:
    """Everything guidance remembers between frames.

    Attributes
    ----------
    mode : Mode
    active_id : int or None
        Track id of the obstacle being avoided.
    clear_since_s : float or None
        Simulation time since which the exit condition has held [s].
    hold_ned_m : tuple of 3 float or None
        Latched HOLD position [m, NED].
    yaw_rad : float or None
        Last commanded yaw [rad] (NED: 0 north, +π/2 east).
    time_s : float or None
        Simulation time of the last step [s].
    memory : ObstacleMemory
    cleared_ids : frozenset of int
        Tracks released after avoidance with the straight path to the goal clear: they
        trigger avoidance again only if that path becomes blocked by them or the vehicle
        enters their boundary.
    aim_dir_ned : tuple of 3 float or None
        Unit direction to the aiming point chosen at the last step (AVOID only).
    unreachable : bool
        HOLD was entered because the goal is unreachable (latched while it stays so).
    progress : Progress or None
        The goal being flown to, the best distance to it and the time spent since without
        getting nearer [m, s].
    on_known_path : bool
        The last step flew a known-space path's first leg (``KNOWN_PATH``).
    escaped_id : int or None
        Track the vehicle escaped from (``INSIDE_BOUNDARY``) and is not yet
        ``escape_clearance_m`` outside of.
    """

    mode: Mode = Mode.NAVIGATE
    active_id: int | None = None
    clear_since_s: float | None = None
    hold_ned_m: tuple[float, float, float] | None = None
    yaw_rad: float | None = None
    time_s: float | None = None
    memory: ObstacleMemory = field(default_factory=ObstacleMemory)
    cleared_ids: frozenset[int] = frozenset()
    aim_dir_ned: tuple[float, float, float] | None = None
    unreachable: bool = False
    progress: Progress | None = None
    on_known_path: bool = False
    escaped_id: int | None = None


@dataclass(frozen=True, eq=False)
class GuidanceOutput:
    """One step's decision.

    Attributes
    ----------
    time_s : float
        Simulation time of the step [s].
    mode : Mode
    reason : Reason
    avoidance_flag : bool
        Fig. 11: True while avoiding (AVOID or HOLD).
    setpoint_ned_m : ndarray, shape (3,)
        Position setpoint [m, NED]: goal, extended aiming direction, escape or hold point.
    yaw_rad : float
        Desired yaw [rad], NED (0 north, +π/2 east), facing the setpoint.
    active_obstacle : TrackedObstacle or None
        The obstacle being avoided.
    aiming_point_ned_m : ndarray, shape (3,) or None
        The Eq. (28) tangent point chosen (AVOID via the planner only).
    tracks : tuple of TrackedObstacle
        The confirmed obstacles of the memory after this step.
    """

    time_s: float
    mode: Mode
    reason: Reason
    avoidance_flag: bool
    setpoint_ned_m: np.ndarray
    yaw_rad: float
    active_obstacle: TrackedObstacle | None
    aiming_point_ned_m: np.ndarray | None
    tracks: tuple[TrackedObstacle, ...]
