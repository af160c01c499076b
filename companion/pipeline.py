"""The companion's pure avoidance pipeline: stereo frame + pose at capture → setpoint.

One call per frame: perception (disparity → depth, paper §4), the known-space map (the
depth folded in with the pose at capture), the collision safety boundaries (Fig. 4) cut
from the map's occupied space (several bounded spheres per extended obstacle,
:mod:`companion.guidance.map_boundaries`), guidance (collision cone, aiming point, mode
switching, Fig. 5), then the safety envelope (the position target
moved no farther than known-free space allows, a speed limit; DESIGN.md "The safety
envelope"). No sockets, files or clocks: the networked service and the lockstep harness
both run exactly this.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass

import numpy as np

from companion.depth_source import DepthSource
from companion.guidance import Guidance, GuidanceConfig, GuidanceOutput, Mode, Reason
from companion.guidance.envelope import EnvelopeConfig, EnvelopeOutput, envelope_step
from companion.guidance.go_look import (
    BLOCKED,
    SEEN_FREE,
    UNSEEN,
    GoLookConfig,
    LookPhase,
    LookState,
    Move,
    held_by_blind_spot_only,
    look_step,
    look_viewpoint,
    look_yaw_rad,
)
from companion.guidance.hold import (
    HoldPlacement,
    HoldPoint,
    WayCheck,
    hold_point,
    inside_any,
    keep_target_out,
)
from companion.guidance.known_path import KnownPath, KnownPathConfig, plan_known_path
from companion.guidance.map_boundaries import (
    MapBoundary,
    MapBoundaryConfig,
    goal_surely_blocked,
    map_boundaries,
    solid_extent,
)
from companion.guidance.path_rules import follow_known_path, warm_up, way_blocked
from companion.known_space import KnownSpace, KnownSpaceConfig
from companion.perception import PerceptionConfig, PerceptionResult, StereoPerception
from companion.phase_times import Phase, PhaseTimes
from companion.position_uncertainty import NO_WIDENING, Widening, widening
from protocols.config import vec3
from protocols.stereo_frame import StereoFrame

__all__ = ["AvoidancePipeline", "PipelineOutput", "PoseAtCapture", "not_guided"]

_RETRY_FRAMES = 2  # a search that found no path is not repeated on the next frame
_ACCEL_WINDOW_NS = 250_000_000  # velocities further apart give no acceleration (a frame was lost)


@dataclass(frozen=True, eq=False)
class PoseAtCapture:
    """The vehicle's pose and velocity at a frame's capture time (LOCAL_NED, FRD), and the
    horizontal accuracy the autopilot states for its position (GPS_RAW_INT ``h_acc``) [m],
    None when it states none."""

    pos_ned_m: np.ndarray
    vel_ned_mps: np.ndarray
    R_ned_from_frd: np.ndarray
    h_acc_m: float | None = None

    @property
    def yaw_rad(self) -> float:
        """Heading of body x in NED [rad] (0 north, +π/2 east), from the rotation."""
        R = self.R_ned_from_frd
        return math.atan2(float(R[1, 0]), float(R[0, 0]))


@dataclass(frozen=True, eq=False)
class PipelineOutput:
    """What one frame produced: the obstacles seen, the guidance decision, the command.

    ``setpoint_ned_m`` and ``yaw_rad`` are what goes to the autopilot: the envelope's
    carrot (never beyond known-free space) and guidance's yaw (facing the direction of
    travel, so the camera looks before the vehicle moves).
    """

    perception: PerceptionResult
    guidance: GuidanceOutput
    envelope: EnvelopeOutput
    boundaries: tuple[MapBoundary, ...] = ()
    # guidance held, and its hold target was moved out of a boundary the vehicle (or the
    # target) was found inside of this frame (drift, wind, a jump of the estimate)
    hold_escape: bool = False
    # guidance steered (not a hold) and the envelope's carrot lay inside a boundary: where
    # it was put instead (companion.guidance.hold.keep_target_out), None when it stood;
    # in a hold, UNSEEN when the vehicle is inside and no way out is seen free (it holds
    # where it is)
    target_kept_out: HoldPlacement | None = None
    # the yaw sent instead of guidance's [rad, NED]: facing a way out of a boundary the
    # camera must look along first (companion.guidance.hold.HoldPoint.look_yaw_rad)
    look_yaw_rad: float | None = None
    # how much wider the vehicle counted for the position estimate's uncertainty, and
    # whether the margins covered it (companion.position_uncertainty)
    widening: Widening = NO_WIDENING
    # the viewpoint guidance steers to for a look at a goal held only by a blind spot
    # [m, NED] (companion.guidance.go_look), None when not looking
    look_ned_m: tuple[float, float, float] | None = None
    # guidance, the envelope and the hold's way out ran; False: the companion was not in
    # control (a pilot's mode), only the map and its boundaries were made, ``guidance``
    # and ``envelope`` stand still at the vehicle (:func:`not_guided`) and are never flown
    guided: bool = True

    @property
    def obstacles(self) -> tuple[MapBoundary, ...]:
        """The obstacles of this frame, as guidance, the envelope, the status, the viewer and
        OBSTACLE_DISTANCE see them: the known-space map's pieces within the detection range,
        each a collision safety boundary (:mod:`companion.guidance.map_boundaries`). Not
        perception's per-frame spheres (``perception.obstacles``: what one frame's depth
        showed, a diagnostic)."""
        return self.boundaries

    @property
    def setpoint_ned_m(self) -> np.ndarray:
        """Position target to send [m, NED]."""
        return self.envelope.setpoint_ned_m

    @property
    def yaw_rad(self) -> float:
        """Yaw to send [rad, NED]: guidance's, or facing a way out to look along."""
        return self.guidance.yaw_rad if self.look_yaw_rad is None else self.look_yaw_rad


class AvoidancePipeline:
    """Perception + guidance toward one goal (Fig. 5), stepped once per stereo frame.

    Parameters
    ----------
    goal_ned_m : sequence of 3 float
        Where to go, LOCAL_NED [m].
    perception, guidance, known_space, envelope : configs (defaults: the paper's 4 m
        threshold etc.).
    depth_source : DepthSource, optional
        The stereo pairs' depth source (:mod:`companion.depth_source` contract); by default
        perception's matcher with ``perception``'s settings.
    """

    def __init__(
        self,
        goal_ned_m,
        perception: PerceptionConfig | None = None,
        guidance: GuidanceConfig | None = None,
        known_space: KnownSpaceConfig | None = None,
        envelope: EnvelopeConfig | None = None,
        *,
        depth_source: DepthSource | None = None,
    ) -> None:
        self.goal_ned_m = np.array(vec3(goal_ned_m, "goal_ned_m"))
        self.perception = StereoPerception(perception, source=depth_source)
        self.guidance = Guidance(guidance)
        self.known_space = KnownSpace(known_space)
        self.envelope_config = EnvelopeConfig() if envelope is None else envelope
        self._last_path = None  # (map frame, goal, KnownPath or None) of the last search
        self._last_vel = None  # (capture_ns, vel_ned_mps) of the last frame: acceleration
        self._brake_ned_m = None  # the envelope's held brake target (step 8), or None
        self.look_config = GoLookConfig()
        self._look = LookState()  # a look at a goal held only by a blind spot (go_look)
        # runs and skips of each phase (timed when the service injects clocks)
        self.phases = PhaseTimes()
        self._widen(self.perception.config.position_uncertainty_m)
        warm_up()

    def _widened(self, h_acc_m: float | None) -> Widening:
        """This frame's widening for the stated accuracy ``h_acc_m`` [m]; the margins
        follow it."""
        p = self.perception.config
        widened = widening(h_acc_m, p.position_uncertainty_m, p.max_position_uncertainty_m)
        if widened.widen_m != self.widen_m:
            self._widen(widened.widen_m)
        return widened

    def _widen(self, widen_m: float) -> None:
        """Count the vehicle ``widen_m`` wider in boundaries, the known-space path and the
        envelope's swept section (:mod:`companion.position_uncertainty`); a path found
        with other margins is searched again."""
        p, e = self.perception.config, self.envelope_config
        self.widen_m = widen_m
        self.vehicle_radius_m = p.vehicle_radius_m + widen_m
        self.boundary_config = MapBoundaryConfig(
            detect_range_m=p.threshold_m, inflate_m=self.vehicle_radius_m + p.safety_margin_m
        )
        self.known_path_config = KnownPathConfig(
            clearance_m=self.vehicle_radius_m + p.safety_margin_m,
            section_radius_m=self.vehicle_radius_m,
            section_half_height_m=e.vehicle_half_height_m,
            near_field_m=e.near_field_m,
            reach_m=self.known_space.config.max_range_m,
        )
        self._last_path = None

    def process(
        self,
        frame: StereoFrame,
        pose: PoseAtCapture,
        *,
        steering: bool = True,
        latency_s: float | None = None,
        guide: bool = True,
    ) -> PipelineOutput:
        """Run one frame; ``pose`` must be the vehicle's at ``frame.capture_ns``;
        ``steering``: whether the vehicle flies the output (guidance's stall count);
        ``latency_s``: the measured latency budget [s] for the stopping rule (None: the
        envelope's configured ``latency_s``; :mod:`companion.guidance.latency`);
        ``guide``: run guidance, the envelope and the hold's way out (False: the
        companion is not in control, issue 34: the frame only feeds the map, whose
        OBSTACLE_DISTANCE the autopilot flies on, and the report; guidance's state
        stands as over a gap without frames, the phases are counted as skipped)."""
        widened = self._widened(pose.h_acc_m)
        phases = self.phases
        seen = self._see(frame, pose)
        with phases.timed(Phase.BOUNDARIES):
            boundaries = map_boundaries(
                self.known_space, pose.pos_ned_m, self.goal_ned_m, self.boundary_config
            )
        if not guide:
            phases.skip(Phase.GUIDANCE, Phase.PLANNING, Phase.ENVELOPE, Phase.HOLD)
            self._brake_ned_m = None  # as when not steering: a brake is held only when flown
            return not_guided(frame, pose, seen, boundaries, widened)
        with phases.timed(Phase.GUIDANCE):
            decision = self._guide(frame, pose, boundaries, steering)
        with phases.timed(Phase.ENVELOPE):
            bounded = self._bound(frame, pose, boundaries, decision, steering, latency_s)
        with phases.timed(Phase.HOLD):
            bounded, escape, kept_out, moved = self._keep_out(pose, boundaries, decision, bounded)
        return PipelineOutput(
            perception=seen,
            guidance=decision,
            envelope=bounded,
            boundaries=boundaries,
            hold_escape=escape is not None and kept_out is None,
            target_kept_out=None if kept_out is None else kept_out.placement,
            look_yaw_rad=look_yaw_rad(self._look, pose.pos_ned_m, self.goal_ned_m, self.look_config)
            if moved is None
            else moved.look_yaw_rad,
            widening=widened,
            look_ned_m=self._look.viewpoint_ned_m
            if self._look.phase is LookPhase.LOOKING
            else None,
        )

    def _guide(self, frame: StereoFrame, pose: PoseAtCapture, boundaries, steering: bool):
        """Guidance's decision on this frame (Fig. 5), with the map's path search; its goal
        is a look's viewpoint while it looks (:meth:`_look_goal`)."""
        return self.guidance.step(
            time_s=frame.capture_ns * 1e-9,
            pos_ned_m=pose.pos_ned_m,
            vel_ned_mps=pose.vel_ned_mps,
            goal_ned_m=self._look_goal(frame.capture_ns * 1e-9, pose, boundaries),
            detections=boundaries,
            yaw_rad=pose.yaw_rad,
            steering=steering,
            goal_surely_blocked=self._goal_surely_blocked(boundaries),
            known_path=self._known_path,
            way_blocked=self._way_blocked,
        )

    def _bound(self, frame, pose, boundaries, decision, steering: bool, latency_s):
        """The safety envelope's carrot and speed bound for guidance's ``decision``."""
        free_distance = functools.partial(
            self.known_space.free_distance_m, solid_ned_m=solid_extent(boundaries)
        )
        bounded = envelope_step(
            pos_ned_m=pose.pos_ned_m,
            vel_ned_mps=pose.vel_ned_mps,
            setpoint_ned_m=decision.setpoint_ned_m,
            free_distance=free_distance,
            vehicle_radius_m=self.vehicle_radius_m,
            max_path_elevation_rad=self.guidance.config.max_aim_elevation_rad,
            config=self.envelope_config,
            latency_s=latency_s,
            heading_rad=pose.yaw_rad,
            accel_ned_mps2=self._accel(frame.capture_ns, pose.vel_ned_mps),
            held_brake_ned_m=self._brake_ned_m if steering else None,
        )
        self._brake_ned_m = bounded.brake_target_ned_m if steering else None
        return bounded

    def _keep_out(self, pose, boundaries, decision, bounded):
        """Invariant 3: a hold target, or the carrot, moved out of a boundary through
        space seen free; returns (the envelope's output with the target sent, the escape
        target or None, the carrot's placement or None, the hold point or None)."""
        escape, kept_out, moved = None, None, None
        way_check = self.way_check(boundaries, pose.yaw_rad)
        if decision.mode is Mode.HOLD:
            moved = self._hold_outside(pose, bounded, boundaries, way_check)
            # no way out seen free: reported as such, not as an escape
            if moved is not None and moved.placement is HoldPlacement.UNSEEN:
                kept_out = moved
        else:
            kept_out = keep_target_out(
                pose.pos_ned_m,
                bounded.setpoint_ned_m,
                boundaries,
                free_m=bounded.free_distance_m,
                clearance_m=self.guidance.config.escape_clearance_m,
                way_check=way_check,
            )
            moved = kept_out
        if moved is not None:
            escape = _read_only(moved.pos_ned_m)
        if escape is not None:
            # the target sent is not the envelope's: a brake target moved out of a
            # boundary is not held (the next frame takes a new stopping point)
            self._brake_ned_m = None
            bounded = dataclasses.replace(bounded, setpoint_ned_m=escape, brake_target_ned_m=None)
        return bounded, escape, kept_out, moved

    def way_check(self, boundaries, heading_rad: float | None) -> WayCheck:
        """The map's question for a way back out of ``boundaries`` (invariants 1 and 3,
        :class:`~companion.guidance.hold.WayCheck`): the envelope's check of a path on the
        known-space map, the vehicle's section as counted now, the boundaries' solid
        extent, the near field excused only along ``heading_rad`` (the camera's)."""
        e = self.envelope_config
        return WayCheck(
            free_distance=functools.partial(
                self.known_space.free_distance_m, solid_ned_m=solid_extent(boundaries)
            ),
            radius_m=self.vehicle_radius_m,
            half_height_m=e.vehicle_half_height_m,
            near_field_m=e.near_field_m,
            heading_rad=heading_rad,
            look_half_angle_deg=e.look_half_angle_deg,
        )

    def _look_goal(self, time_s: float, pose: PoseAtCapture, boundaries) -> np.ndarray:
        """Guidance's goal this frame: the viewpoint of the one look at a goal held only by
        a blind spot, started when guidance holds for it (:mod:`companion.guidance.go_look`),
        else the goal."""
        goal = self.goal_ned_m
        state = self.guidance.state
        looking = self._look.phase is LookPhase.LOOKING
        self._look = look_step(
            self._look,
            time_s=time_s,
            pos_ned_m=pose.pos_ned_m,
            goal_ned_m=goal,
            blind_only=held_by_blind_spot_only(boundaries, goal, self.boundary_config.inflate_m),
            held=inside_any(goal, boundaries),
            holding=state.mode is Mode.HOLD and (looking or state.unreachable),
            viewpoint=functools.partial(self._viewpoint, pose, boundaries),
            config=self.look_config,
        )
        return self._look.steer_to(goal)

    def _viewpoint(self, pose: PoseAtCapture, boundaries) -> np.ndarray | None:
        """Where to look at the goal from (:func:`~companion.guidance.go_look.look_viewpoint`):
        the map's surfaces near the goal may hide it; the move there must be seen free."""
        pos, goal = np.asarray(pose.pos_ned_m, dtype=float), self.goal_ned_m
        reach_m = float(np.linalg.norm(goal - pos)) * 1.25 + self.look_config.max_look_m
        occupied = self.known_space.occupied_points_ned_m()
        occupied = occupied[np.linalg.norm(occupied - goal, axis=1) <= reach_m]
        check = self.way_check(boundaries, pose.yaw_rad)

        def reachable(start, end) -> Move:
            if check.seen_free(start, end, looked=True):
                return SEEN_FREE
            return BLOCKED if self._way_blocked(start, end) else UNSEEN

        return look_viewpoint(pos, goal, occupied, boundaries, reachable, self.look_config)

    def _goal_surely_blocked(self, boundaries) -> bool:
        """A boundary holds the goal for certain (``map_boundaries.goal_surely_blocked``)
        and the surface within its inflation of the goal was seen from near
        (:meth:`~companion.known_space.KnownSpace.seen_near`: hit from where a pixel of
        disparity is at most a voxel). A surface seen only from far may be a depth bias
        (the suite's Monte Carlo seed 102: 0.5-0.9 m in front of the sphere, hit from
        7.7 m): the hold before it stands but is not latched, so it ends once nearer
        frames see through it."""
        if not goal_surely_blocked(boundaries, self.goal_ned_m, self.boundary_config):
            return False
        c = self.known_space.config
        reach_m = self.boundary_config.inflate_m + 0.5 * math.sqrt(3.0) * c.voxel_m
        return self.known_space.seen_near(self.goal_ned_m, reach_m)

    def _accel(self, capture_ns: int, vel_ned_mps) -> np.ndarray | None:
        """The vehicle's acceleration [m/s², NED]: the change of velocity since the last
        frame, when it came at most ``_ACCEL_WINDOW_NS`` before (None otherwise)."""
        vel = np.array(vel_ned_mps, dtype=float)
        last, self._last_vel = self._last_vel, (capture_ns, vel)
        if last is None or not 0 < capture_ns - last[0] <= _ACCEL_WINDOW_NS:
            return None
        return (vel - last[1]) / ((capture_ns - last[0]) * 1e-9)

    def _see(self, frame: StereoFrame, pose: PoseAtCapture):
        """Perception of ``frame`` and its depth into the known-space map (no depth: the
        vehicle's own cell is marked)."""
        with self.phases.timed(Phase.PERCEPTION):
            seen = self.perception.process(frame, pose.pos_ned_m, pose.R_ned_from_frd)
        with self.phases.timed(Phase.KNOWN_SPACE):
            self._fold_in(seen, frame, pose)
        return seen

    def _fold_in(self, seen, frame: StereoFrame, pose: PoseAtCapture) -> None:
        """The frame's depth into the known-space map (no depth: the vehicle's own cell)."""
        if seen.depth_m is not None:
            self.known_space.integrate(
                seen.depth_m,
                frame.intrinsics,
                pose.pos_ned_m,
                pose.R_ned_from_frd,
                blind_band_px=seen.blind_band_px,
                trusted_range_m=seen.trusted_range_m,
            )
        else:
            self.known_space.mark_vehicle(pose.pos_ned_m)

    def _known_path(self, pos_ned_m, goal_ned_m, spheres) -> KnownPath | None:
        """Guidance's search of the known-space map (:mod:`companion.guidance.known_path`),
        bounded per frame: a path found is followed, not searched again, for up to
        ``replan_frames`` map frames while it stays valid
        (:func:`~companion.guidance.path_rules.follow_known_path`: a check of its voxels,
        a fraction of a search); a search that found none is not repeated on the next
        frame (``benchmarks/bench_guidance_path.py`` prints the costs)."""
        with self.phases.timed(Phase.PLANNING):
            return self._search_or_follow(pos_ned_m, goal_ned_m, spheres)

    def _search_or_follow(self, pos_ned_m, goal_ned_m, spheres) -> KnownPath | None:
        ks = self.known_space
        last = self._last_path
        if last is not None and np.array_equal(last[1], goal_ned_m):
            frame, _, path = last
            age = ks.frames - frame
            if path is None and age < _RETRY_FRAMES:
                return None
            if path is not None and age < self.known_path_config.replan_frames:
                followed = follow_known_path(
                    path, ks.grid, ks.origin_vox, ks.config.voxel_m, pos_ned_m, goal_ned_m,
                    spheres=spheres, config=self.known_path_config,
                )  # fmt: skip
                if followed is not None:
                    return followed
        path = plan_known_path(
            ks.grid, ks.origin_vox, ks.config.voxel_m, pos_ned_m, goal_ned_m,
            spheres=spheres, config=self.known_path_config,
        )  # fmt: skip
        self._last_path = (ks.frames, np.array(goal_ned_m, dtype=float), path)
        return path

    def _way_blocked(self, start_ned_m, end_ned_m) -> bool:
        """Guidance's question to the known-space map: a surface seen in the way
        (:func:`~companion.guidance.path_rules.way_blocked`)."""
        ks = self.known_space
        return way_blocked(
            ks.grid, ks.origin_vox, ks.config.voxel_m, start_ned_m, end_ned_m,
            config=self.known_path_config,
        )  # fmt: skip

    def _hold_outside(
        self, pose: PoseAtCapture, bounded: EnvelopeOutput, boundaries, way_check
    ) -> HoldPoint | None:
        """Invariant 3 of the envelope for guidance's holds: when the vehicle or its hold
        target is inside a boundary, the target that leads out through space seen free
        (:func:`~companion.guidance.hold.hold_point` with the map's ``way_check``); None
        when both are outside (the hold target stands)."""
        if not (
            inside_any(pose.pos_ned_m, boundaries) or inside_any(bounded.setpoint_ned_m, boundaries)
        ):
            return None
        return hold_point(
            pose.pos_ned_m,
            pose.vel_ned_mps,
            boundaries,
            latency_s=bounded.latency_s,
            accel_mps2=self.envelope_config.accel_mps2,
            clearance_m=self.guidance.config.escape_clearance_m,
            way_check=way_check,
        )


def not_guided(
    frame: StereoFrame, pose: PoseAtCapture, seen, boundaries, widened: Widening
) -> PipelineOutput:
    """A frame's output when guidance did not run (the companion not in control): its
    perception and the map's boundaries; guidance navigating with no threat and the
    envelope standing still, both at the vehicle's position and yaw (no setpoint of
    them is ever sent: the core sends only while it steers), the speed measured, no
    speed bound stated (0 m/s, never flown)."""
    here = _read_only(pose.pos_ned_m)
    decision = GuidanceOutput(
        time_s=frame.capture_ns * 1e-9,
        mode=Mode.NAVIGATE,
        reason=Reason.NO_THREAT,
        avoidance_flag=False,
        setpoint_ned_m=here,
        yaw_rad=pose.yaw_rad,
        active_obstacle=None,
        aiming_point_ned_m=None,
        tracks=(),
    )
    still = EnvelopeOutput(
        setpoint_ned_m=here,
        path_dir_ned=np.zeros(3),
        free_distance_m=0.0,
        stopping_distance_m=0.0,
        speed_limit_mps=0.0,
        speed_mps=float(np.linalg.norm(pose.vel_ned_mps)),
        limited=False,
        overspeed=False,
    )
    return PipelineOutput(
        perception=seen,
        guidance=decision,
        envelope=still,
        boundaries=boundaries,
        widening=widened,
        guided=False,
    )


def _read_only(point) -> np.ndarray:
    target = np.array(point, dtype=float)
    target.setflags(write=False)
    return target
