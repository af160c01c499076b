"""Navigation ↔ avoidance switching (paper Fig. 5) with hysteresis and obstacle memory.

One call per perception frame (30 Hz): boundary spheres in, a decision out. Pure: the
state is a frozen :class:`GuidanceState` threaded through :func:`guidance_step`
(:class:`Guidance` wraps it for callers that prefer an object); time is the caller's
simulation time [s], there is no clock here.

Each step
---------
1. Merge the detections into the obstacle memory (:mod:`companion.guidance.memory`).
2. Reference: the velocity; the direction to the goal below ``min_speed_mps`` (so a hovering
   vehicle does not start into an obstacle) or when staged (``stage_yaw.staged_move``).
3. On or inside a boundary sphere → AVOID (``INSIDE_BOUNDARY``): setpoint radially out of
   the deepest one, ``escape_clearance_m`` beyond its surface, slid by
   ``min_setpoint_distance_m`` along the direction of travel (the previous aiming
   direction while going around it): a vehicle that strays into a boundary that grew
   (the memory never shrinks one) keeps going around instead of backing out.
   Hysteresis (issue 36): the obstacle escaped from stays active (``HYSTERESIS``, the
   aiming point leading round it) while the vehicle is less than ``escape_clearance_m``
   outside its boundary and the direction to the goal lies in its cone widened by
   ``exit_margin_rad``. Released at once by the "behind" rule of step 5 (the escape
   velocity points away from the centre), guidance navigated straight back in: 39
   switches between ``inside_boundary`` and ``navigate`` before a thin wall.
4. *Threats* (paper §5: critical): the reference lies inside the obstacle's cone and its
   surface is nearer than the goal plus ``goal_clearance_m``.
5. Hysteresis on the active obstacle (AVOID/HOLD), checked in this order. It stays
   active while it is a threat, and while the straight path to the goal crosses its
   sphere (``GOAL_BLOCKED``: the aiming point keeps leading around it instead of turning
   back into it, the chatter the paper's "return as soon as the velocity leaves the cone"
   would cause). Otherwise it is released at once if its centre is behind the vehicle
   (``(c - p)·v ≤ 0``); else it stays (``HYSTERESIS``) until the reference has been
   outside its cone widened by ``exit_margin_rad`` continuously for
   ``min_clear_time_s``. Forgotten by the memory → released.
   A released obstacle is *cleared*: the straight path to the goal no longer crosses it,
   so it is not a threat again unless that path becomes blocked by it (or the vehicle
   enters its boundary, step 3). Close to a boundary the cone is nearly a half-space and
   the velocity, turning from the tangent toward the goal, sweeps through it although the
   path bulges away from the obstacle; without this rule the flag chatters there.
6. Active obstacle: the threat with the nearest surface, or the kept one if nearer.
   None → NAVIGATE (setpoint = goal). A threat whose sphere holds the goal → HOLD
   (``GOAL_UNREACHABLE``): a guard only, as the goal guidance steers to is never inside
   a confirmed boundary (:mod:`companion.guidance.goal_stop`).
7. AVOID: :func:`~companion.guidance.planner.choose_aiming_point` over all remembered
   obstacles, candidates from the cluster of cones overlapping the active and threatening
   ones. Nothing free → HOLD (``NO_FREE_DIRECTION``). Eq. (28)'s reference is the
   velocity on entry and the previous aiming direction afterwards (below).
   With a ``known_path`` search given (the pipeline binds the known-space map), the cone
   rule is second-guessed where it fails (issue 36): when it leaves no admissible
   direction, or while the straight path to the goal is blocked and a path through space
   seen free leads past the obstacle through a way the cones close, guidance flies that
   path's first leg (``KNOWN_PATH``, :func:`~companion.guidance.path_rules.
   prefer_known_path`); the safety envelope bounds it like any setpoint.

After step 7, no progress and every stall reported: :mod:`companion.guidance.progress`.

Unreachable goal (the goal inside a confirmed boundary): guidance steers to a stop
point outside the goal's obstacle and holds there, ``GOAL_UNREACHABLE``
(:mod:`companion.guidance.goal_stop`).

Committing to a side
--------------------
On entry the aiming point is Eq. (28)'s: the tangent point nearest the velocity (or the
head-on tie-break). While the same obstacle stays active, the reference becomes the
previous aiming direction, i.e. the commanded direction of travel, so the aiming point
moves continuously around the circle on the side chosen at entry. With several spheres
per obstacle (map pieces) the active one changes as pieces come into range; the side is
kept while the previously active one is in the cluster of overlapping cones avoided.
Using the actual velocity every frame is unstable in closed loop: the horizontal channel
is tilt-limited (±15°) while the vertical one is not, so any small vertical part of the
aiming direction grows the vertical velocity faster than the lateral one, which pulls
the next aiming point further up or down; in the §6 scenario a 1° perception bias turned a side-step
into a climb within half a second.

Setpoint while avoiding
-----------------------
A position target *at* the tangent point makes the position loop brake there, and the
tangent point itself lies on the boundary sphere. The setpoint is therefore placed along
the aiming direction at ``clip(L + setpoint_extension_m, min_setpoint_distance_m,
max_setpoint_distance_m)`` from the vehicle (``L`` the tangent length). The ray from the
vehicle along that direction is outside every other cone (planner) and only touches the
active sphere, so any point on it is collision-free; recomputed every frame it acts as a
carrot that leads around the sphere. Without the extension and the floor the carrot
collapses as the vehicle skims the boundary (``L → 0``): a kinematic §6 run then stalls
beside the obstacle. ``aiming_point_ned_m`` in the output is the tangent point itself.

HOLD latches the position where it was entered; the link may map it to BRAKE/LOITER.
The avoidance flag of Fig. 11 is ``mode is not NAVIGATE`` (HOLD is an avoidance action).

Yaw: the vehicle faces the horizontal direction to its setpoint (the direction it is
about to travel), so the forward camera looks where it goes; in HOLD and within
``yaw_min_distance_m`` of the setpoint, the previous yaw is held.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np

from companion.guidance._vec import norm3
from companion.guidance.cone import (
    SphereLike,
    _collision_cone,
    _contains_direction,
    escape_point,
    segment_intersects_sphere,
)
from companion.guidance.config import GuidanceConfig
from companion.guidance.goal_stop import hold_at_stop_point, inside_ball, same_obstacle, stop_point
from companion.guidance.hold import inside_any, nearest_outside
from companion.guidance.known_path import KnownPath
from companion.guidance.memory import TrackedObstacle, update_memory
from companion.guidance.modes import Mode, Reason
from companion.guidance.path_rules import prefer_known_path
from companion.guidance.planner import choose_aiming_point, overlapping_cluster
from companion.guidance.progress import Progress, watch_progress
from companion.guidance.stage_yaw import stage_yaw_rad, staged_move
from companion.guidance.step_types import GuidanceOutput, GuidanceState
from protocols.config import vec3

__all__ = [
    "Guidance",
    "GuidanceOutput",
    "GuidanceState",
    "Mode",
    "Progress",
    "Reason",
    "guidance_step",
]


KnownPathFn = Callable[[np.ndarray, np.ndarray, list], KnownPath | None]
"""``(pos_ned_m, goal_ned_m, spheres) → KnownPath or None``: a search of the known-space map
(:func:`companion.guidance.known_path.plan_known_path` with the map bound)."""

WayBlockedFn = Callable[[np.ndarray, np.ndarray], bool]
"""``(start_ned_m, end_ned_m) → bool``: the vehicle's body moving straight between them
meets a surface the map has seen (:func:`companion.guidance.path_rules.way_blocked`)."""


def guidance_step(
    state: GuidanceState,
    *,
    time_s: float,
    pos_ned_m,
    vel_ned_mps,
    goal_ned_m,
    detections: Iterable[SphereLike] = (),
    yaw_rad: float | None = None,
    config: GuidanceConfig | None = None,
    steering: bool = True,
    goal_surely_blocked: bool = True,
    known_path: KnownPathFn | None = None,
    way_blocked: WayBlockedFn | None = None,
) -> tuple[GuidanceState, GuidanceOutput]:
    """Advance guidance by one perception frame.

    Parameters
    ----------
    state : GuidanceState
        After the previous step (``GuidanceState()`` to start).
    time_s : float
        Simulation time of this frame [s]; must not decrease.
    pos_ned_m, vel_ned_mps : array_like, shape (3,)
        Vehicle position [m] and velocity [m/s] at the frame's capture time, NED.
    goal_ned_m : array_like, shape (3,)
        Navigation goal [m, NED].
    detections : iterable of SphereLike
        This frame's (inflated) boundary spheres.
    yaw_rad : float, optional
        Current yaw [rad]; the first yaw command falls back to it (setpoint too close).
    config : GuidanceConfig, optional (``GuidanceConfig()``)
    steering : bool
        The vehicle flies this step's setpoint (not a failsafe hold or a pilot's mode):
        only such time counts toward ``NO_PROGRESS``.
    goal_surely_blocked : bool
        A sphere holds the goal for certain, not by a blind spot only: a ``GOAL_UNREACHABLE``
        hold is latched (``progress.watch_progress``, ``map_boundaries.goal_surely_blocked``).
    known_path, way_blocked : callable, optional
        The known-space map's path search and its "surface in the way" (step 7); None:
        the cone rule alone.

    Returns
    -------
    state : GuidanceState
        State for the next step.
    output : GuidanceOutput
        This step's decision.
    """
    cfg = GuidanceConfig() if config is None else config
    time_s = _check_time(state, time_s)
    pos = np.array(vec3(pos_ned_m, "pos_ned_m"))
    vel = np.array(vec3(vel_ned_mps, "vel_ned_mps"))
    goal_in = vec3(goal_ned_m, "goal_ned_m")
    goal = np.array(goal_in)
    memory = update_memory(
        state.memory, detections, time_s=time_s, pos_ned_m=pos, vel_ned_mps=vel,
        goal_ned_m=goal, config=cfg,
    )  # fmt: skip
    tracks = tuple(t for t in memory.tracks if t.confirmed)
    cones = _cones(pos, tracks)
    stop = stop_point(pos, goal, tracks, cfg)  # unreachable goal: the stop point instead
    unreachable = stop is not None
    if unreachable:
        goal = stop
    ref = _reference(pos, vel, goal, cfg)
    f = _Frame(time_s, pos, goal, ref, tracks, cones, known_path, way_blocked)
    live_ids = {t.track_id for t in tracks}
    d = _Decision(setpoint=goal, cleared={i for i in state.cleared_ids if i in live_ids})
    inside = [i for i, c in enumerate(cones) if c.apex_inside]
    if inside:
        _escape_boundary(state, f, inside, d, cfg)
    else:
        _avoid_threats(state, f, d, cfg)
    if unreachable:
        hold_at_stop_point(state, f, d, cfg)
    progress = watch_progress(state, f, tuple(goal_in), d, cfg, steering, goal_surely_blocked)
    hold = _latch_hold(state, f, d)
    yaw = _yaw(state, f, d, yaw_rad, cfg)
    return _outputs(f, d, memory, hold, yaw, progress)


def _cones(pos: np.ndarray, tracks) -> list:
    apex = pos.copy()  # one read-only apex shared by this step's cones
    return [_collision_cone(apex, t.sphere) for t in tracks]


def _check_time(state: GuidanceState, time_s: float) -> float:
    time_s = float(time_s)
    if not math.isfinite(time_s):
        raise ValueError(f"time_s must be finite, got {time_s!r}")
    if state.time_s is not None and time_s < state.time_s:
        raise ValueError(f"simulation time went backwards: {time_s} s after {state.time_s} s")
    return time_s


@dataclass(frozen=True, eq=False)
class _Frame:
    """What one step sees: time, vehicle, (stop-point) goal, reference, confirmed tracks."""

    time_s: float
    pos: np.ndarray
    goal: np.ndarray
    ref: np.ndarray
    tracks: tuple[TrackedObstacle, ...]
    cones: list
    plan: KnownPathFn | None = None
    blocked: WayBlockedFn | None = None

    _blocked: dict[int, bool] = field(default_factory=dict, repr=False)

    @functools.cached_property
    def goal_dist(self) -> float:
        return norm3(self.goal - self.pos)

    @functools.cached_property
    def has_ref(self) -> bool:
        return bool(np.any(self.ref != 0.0))

    def goal_blocked(self, i: int) -> bool:
        """The straight path to the goal crosses track ``i``'s sphere (asked once per
        track and step, remembered)."""
        blocked = self._blocked.get(i)
        if blocked is None:
            blocked = self._blocked[i] = self.goal_dist > 1e-9 and segment_intersects_sphere(
                self.pos, self.goal, self.tracks[i].sphere
            )
        return blocked


@dataclass(eq=False)
class _Decision:
    """The step's decision as the phases build it."""

    setpoint: np.ndarray
    cleared: set[int]
    mode: Mode = Mode.NAVIGATE
    reason: Reason = Reason.NO_THREAT
    active: int | None = None
    clear_since: float | None = None
    aim: np.ndarray | None = None
    aim_dir: tuple[float, float, float] | None = None
    on_path: bool = False
    escaped: int | None = None


def _reference(pos, vel, goal, cfg: GuidanceConfig) -> np.ndarray:
    """Step 2: the velocity; the direction to the goal below ``min_speed_mps`` or staged."""
    to_goal = goal - pos
    moving = 0.0 < norm3(vel) >= cfg.min_speed_mps
    if moving and not staged_move(pos, goal, cfg.max_aim_elevation_rad):
        return vel
    if norm3(to_goal) > 1e-9:
        return to_goal
    return np.zeros(3)


def _escape_boundary(state, f: _Frame, inside: list[int], d: _Decision, cfg) -> None:
    """Step 3: on or inside a boundary sphere → out of the deepest one, sliding along."""
    cones, tracks = f.cones, f.tracks
    active = max(inside, key=lambda i: (cones[i].radius_m - cones[i].distance_m, -i))
    d.active = active
    d.mode, d.reason = Mode.AVOID, Reason.INSIDE_BOUNDARY
    d.escaped = tracks[active].track_id
    same = state.active_id == tracks[active].track_id
    keep_going = np.asarray(state.aim_dir_ned) if state.aim_dir_ned is not None and same else f.ref
    d.setpoint = escape_point(
        f.pos,
        tracks[active].sphere,
        clearance_m=cfg.escape_clearance_m,
        reference_ned=keep_going,
        slide_m=cfg.min_setpoint_distance_m,
    )
    spheres = [t.sphere for t in tracks]
    if inside_any(d.setpoint, spheres):
        # out of the deepest piece into a neighbouring one (a wall is many pieces): the
        # nearest point out of all of them, the radial way out preferred
        out = nearest_outside(
            f.pos, spheres, clearance_m=cfg.escape_clearance_m, prefer_ned=d.setpoint - f.pos
        )
        d.setpoint = d.setpoint if out is None else out
    d.aim_dir = state.aim_dir_ned if same else None


def _avoid_threats(state, f: _Frame, d: _Decision, cfg) -> None:
    """Steps 4–7: threats, hysteresis on the active obstacle, the aiming point or HOLD."""
    cones, tracks = f.cones, f.tracks
    threats = [
        i
        for i, c in enumerate(cones)
        if f.has_ref
        and (c.surface_distance_m <= f.goal_dist + cfg.goal_clearance_m or f.goal_blocked(i))
        and _contains_direction(c, f.ref, 0.0)
        and (tracks[i].track_id not in d.cleared or f.goal_blocked(i))
    ]
    kept, kept_reason = _keep_active(state, f, threats, d, cfg)
    candidates = threats if kept is None else sorted({*threats, kept})
    if not candidates:
        return
    active = min(candidates, key=lambda i: (cones[i].surface_distance_m, i))
    d.active = active
    d.reason = Reason.CRITICAL if active in threats else kept_reason
    if d.reason is not Reason.HYSTERESIS:
        d.clear_since = None
    if active in threats and inside_ball(f.goal, cones[active]):
        d.mode, d.reason = Mode.HOLD, Reason.GOAL_UNREACHABLE  # a guard: see stop_point
    else:
        _plan_aim(state, f, sorted({active, *threats}), d, cfg)


def _keep_active(state, f: _Frame, threats: list[int], d: _Decision, cfg):
    """Step 5: whether the previous active obstacle stays active, and why (hysteresis)."""
    kept: int | None = None
    kept_reason = Reason.CRITICAL
    if state.mode is not Mode.NAVIGATE:
        kept = next((i for i, t in enumerate(f.tracks) if t.track_id == state.active_id), None)
    if kept is None or kept in threats:
        return kept, kept_reason
    cone = f.cones[kept]
    if (
        f.tracks[kept].track_id == state.escaped_id
        and cone.surface_distance_m < cfg.escape_clearance_m
        and _contains_direction(cone, f.goal - f.pos, cfg.exit_margin_rad)
    ):
        d.escaped = state.escaped_id  # just escaped, the goal beyond: not released yet
        return kept, Reason.HYSTERESIS
    behind = not f.has_ref or float(f.ref @ cone.axis_ned) <= 0.0
    obstacle = same_obstacle(f.tracks, [kept])
    if any(f.goal_blocked(i) for i in obstacle):
        kept_reason = Reason.GOAL_BLOCKED
    elif behind:
        d.cleared.update(f.tracks[i].track_id for i in obstacle)
        kept = None
    elif _contains_direction(cone, f.ref, cfg.exit_margin_rad):
        kept_reason = Reason.HYSTERESIS
    else:
        since = f.time_s if state.clear_since_s is None else state.clear_since_s
        if f.time_s - since >= cfg.min_clear_time_s:
            d.cleared.update(f.tracks[i].track_id for i in obstacle)
            kept = None
        else:
            kept_reason, d.clear_since = Reason.HYSTERESIS, since
    return kept, kept_reason


def _plan_aim(state, f: _Frame, seeds: list[int], d: _Decision, cfg) -> None:
    """Step 7: the aiming point (Eq. 28) and the carrot along it, or HOLD if none."""
    cluster = overlapping_cluster(f.cones, seeds, margin_rad=cfg.cone_margin_rad)
    plan_ref = f.ref
    if (
        state.mode is Mode.AVOID
        and state.aim_dir_ned is not None
        and state.active_id in {f.tracks[i].track_id for i in cluster}
    ):
        # Commit to the side chosen on entry: Eq. (28) against the previous
        # aiming direction (the commanded velocity) rather than the actual
        # velocity; see "Committing to a side" in the module docstring. The
        # obstacle is the cluster (several map pieces), not one sphere.
        plan_ref = _level_small_tilt(np.asarray(state.aim_dir_ned), cfg.tie_angle_rad)
    choice = choose_aiming_point(
        f.cones,
        plan_ref,
        n_candidates=cfg.n_candidates,
        tie_angle_rad=cfg.tie_angle_rad,
        cone_margin_rad=cfg.cone_margin_rad,
        candidate_indices=cluster,
        max_elevation_rad=cfg.max_aim_elevation_rad,
        vertical_weight=cfg.vertical_weight,
        cluster_tie=plan_ref is f.ref,
    )
    carrot = None
    if choice is not None:
        reach = min(
            max(choice.distance_m + cfg.setpoint_extension_m, cfg.min_setpoint_distance_m),
            cfg.max_setpoint_distance_m,
        )
        carrot = f.pos + choice.direction_ned * reach
    if _fly_known_path(state, f, cluster, choice, carrot, d, cfg):
        return
    if choice is None:
        d.mode, d.reason = Mode.HOLD, Reason.NO_FREE_DIRECTION
        return
    d.mode = Mode.AVOID
    d.aim = choice.aiming_point_ned_m
    d.aim_dir = tuple(float(x) for x in choice.direction_ned)
    d.setpoint = carrot


def _level_small_tilt(direction: np.ndarray, tilt_rad: float) -> np.ndarray:
    """The committed reference with a climb or descent within ``tilt_rad`` levelled.

    Its horizontal part keeps the side chosen on entry. A small vertical part is the map
    pieces' accident (a near-tie between passing a little above or a little below), which
    the previous aiming direction would otherwise carry on frame after frame: with the
    autopilot's velocity integrator or the companion's climb statement the §6 vehicle
    followed an aim 2.3° down for 7 s to 0.67 m below its altitude. A deliberate pass over
    or under (steeper than ``tilt_rad``) is kept."""
    horizontal = math.hypot(float(direction[0]), float(direction[1]))
    if horizontal < 1e-9 or abs(float(direction[2])) > math.tan(tilt_rad) * horizontal:
        return direction
    return np.array([direction[0] / horizontal, direction[1] / horizontal, 0.0])


def _fly_known_path(state, f: _Frame, cluster, choice, carrot, d, cfg) -> bool:
    """Step 7's second guess: the first leg of a path through known-free space, where the
    cone rule fails (:func:`~companion.guidance.path_rules.prefer_known_path`): no
    admissible direction (``choice`` None), its ``carrot`` blocked in known space, or a
    way the map shows open closed by the cones."""
    if f.plan is None:
        return False
    cone_has_direction = choice is not None
    cone_way_m = math.inf
    if choice is not None:
        aim = np.asarray(choice.aiming_point_ned_m)
        cone_way_m = norm3(aim - f.pos) + norm3(f.goal - aim)
    kept = state.on_known_path and state.mode is Mode.AVOID
    goal_blocked = any(f.goal_blocked(i) for i in cluster)
    blocked = carrot is not None and f.blocked is not None and f.blocked(f.pos, carrot)
    if cone_has_direction and not (kept or goal_blocked or blocked):
        return False
    path = f.plan(f.pos, f.goal, [t.sphere for t in f.tracks])
    if not prefer_known_path(
        path, f.pos, f.goal, cone_has_direction=cone_has_direction,
        cones=[f.cones[i] for i in cluster], kept=kept,
        min_progress_m=cfg.known_path_progress_m, cone_way_m=cone_way_m,
        cone_blocked=blocked,
        cone_dir_ned=None if choice is None else np.asarray(choice.direction_ned),
    ):  # fmt: skip
        return False
    leg = np.array(path.leg_end_ned_m, dtype=float)
    d.mode, d.reason, d.on_path = Mode.AVOID, Reason.KNOWN_PATH, True
    d.aim = None
    d.aim_dir = tuple(float(x) for x in (leg - f.pos) / norm3(leg - f.pos))
    d.setpoint = leg
    return True


def _latch_hold(state, f: _Frame, d: _Decision) -> tuple[float, float, float] | None:
    """HOLD latches the position where it was entered; the setpoint is that point."""
    if d.mode is not Mode.HOLD:
        return None
    if state.mode is Mode.HOLD and state.hold_ned_m is not None:
        hold = state.hold_ned_m
    else:
        hold = (float(f.pos[0]), float(f.pos[1]), float(f.pos[2]))
    d.setpoint = np.array(hold)
    d.clear_since = None
    return hold


def _yaw(state, f: _Frame, d: _Decision, yaw_rad: float | None, cfg) -> float:
    """Face the horizontal direction to the setpoint; else hold the previous yaw, turned
    off a boundary when a setpoint straight above or below is staged into one
    (:func:`~companion.guidance.stage_yaw.stage_yaw_rad`)."""
    previous_yaw = state.yaw_rad if state.yaw_rad is not None else yaw_rad
    to_setpoint = d.setpoint - f.pos
    if d.mode is not Mode.HOLD and math.hypot(to_setpoint[0], to_setpoint[1]) >= max(
        cfg.yaw_min_distance_m, 1e-9
    ):
        return math.atan2(float(to_setpoint[1]), float(to_setpoint[0]))
    if previous_yaw is None:
        return 0.0
    if d.mode is not Mode.HOLD:
        spheres = [(t.sphere.center_ned_m, t.sphere.radius_m) for t in f.tracks]
        turned = stage_yaw_rad(
            f.pos, d.setpoint, float(previous_yaw), spheres, cfg.max_aim_elevation_rad
        )
        if turned is not None:
            return turned
    return float(previous_yaw)


def _outputs(f: _Frame, d: _Decision, memory, hold, yaw: float, progress: Progress):
    """The next state and this step's output, arrays frozen."""
    setpoint = np.array(d.setpoint, dtype=float)
    setpoint.setflags(write=False)
    aim = d.aim
    if aim is not None:
        aim = np.array(aim, dtype=float)
        aim.setflags(write=False)
    active_track = None if d.active is None else f.tracks[d.active]
    new_state = GuidanceState(
        mode=d.mode,
        active_id=None if active_track is None else active_track.track_id,
        clear_since_s=d.clear_since,
        hold_ned_m=hold,
        yaw_rad=yaw,
        time_s=f.time_s,
        memory=memory,
        cleared_ids=frozenset(d.cleared),
        aim_dir_ned=d.aim_dir,
        unreachable=d.mode is Mode.HOLD and d.reason is Reason.GOAL_UNREACHABLE,
        progress=progress,
        on_known_path=d.on_path and d.mode is Mode.AVOID,
        escaped_id=d.escaped,
    )
    output = GuidanceOutput(
        time_s=f.time_s,
        mode=d.mode,
        reason=d.reason,
        avoidance_flag=d.mode is not Mode.NAVIGATE,
        setpoint_ned_m=setpoint,
        yaw_rad=yaw,
        active_obstacle=active_track,
        aiming_point_ned_m=aim,
        tracks=f.tracks,
    )
    return new_state, output


class Guidance:
    """Stateful convenience wrapper around :func:`guidance_step`.

    Parameters
    ----------
    config : GuidanceConfig, optional
        Defaults to ``GuidanceConfig()``.
    """

    def __init__(self, config: GuidanceConfig | None = None) -> None:
        self.config = GuidanceConfig() if config is None else config
        self.state = GuidanceState()

    def reset(self) -> None:
        """Forget everything (mode, memory, yaw)."""
        self.state = GuidanceState()

    def step(
        self,
        *,
        time_s: float,
        pos_ned_m,
        vel_ned_mps,
        goal_ned_m,
        detections: Iterable[SphereLike] = (),
        yaw_rad: float | None = None,
        steering: bool = True,
        goal_surely_blocked: bool = True,
        known_path: KnownPathFn | None = None,
        way_blocked: WayBlockedFn | None = None,
    ) -> GuidanceOutput:
        """Run :func:`guidance_step` on the held state; returns the output."""
        self.state, output = guidance_step(
            self.state,
            time_s=time_s,
            pos_ned_m=pos_ned_m,
            vel_ned_mps=vel_ned_mps,
            goal_ned_m=goal_ned_m,
            detections=detections,
            yaw_rad=yaw_rad,
            config=self.config,
            steering=steering,
            goal_surely_blocked=goal_surely_blocked,
            known_path=known_path,
            way_blocked=way_blocked,
        )
        return output
