"""Lockstep run: plant + synthetic stereo camera + the companion's mission, one process.

Deterministic in simulation time and free of sockets: each camera period the plant is
advanced, the stereo pair rendered at the true pose, the companion's
:class:`~companion.core.Mission` (the same waypoint sequencing and avoidance pipeline the
networked companion's core runs per frame) turns it into a setpoint and a speed limit,
and plant-sim's ArduCopter GUIDED flies them (:mod:`evaluation.lockstep_autopilot`: the
same mode logic, target shaping and DO_CHANGE_SPEED as the networked plant-sim, ticking
at 50 Hz) until the next frame. The pose handed to the mission is the plant's at the
frame's capture time, as the networked companion interpolates it from telemetry.
What lockstep leaves out is the link itself: mode changes, failsafes, takeover (tested in
process on :class:`~companion.core.CompanionCore`).
"""

from __future__ import annotations

import copy
import functools
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from companion.core.mission import Mission, MissionStep
from companion.guidance import GuidanceConfig, Mode
from companion.guidance.envelope import EnvelopeConfig
from companion.guidance.hold import inside_any
from companion.known_space import KnownSpaceConfig
from companion.perception import PerceptionConfig
from companion.pipeline import PoseAtCapture
from companion.proximity.sectors import ProximityConfig, sectors_from_map
from evaluation.history import History
from evaluation.lockstep_autopilot import LockstepAutopilot, autopilot_params
from evaluation.scenes import Scene
from evaluation.truth_perception import TruthDepthSource
from plant_sim.depth_camera import CameraEncoding, DepthNoiseParams, depth_frame
from plant_sim.disturbance import Disturbances
from plant_sim.params import ControlParams, QuadrotorParams
from plant_sim.stereo_camera import RenderParams, StereoCameraRenderer
from plant_sim.vehicle import Quadrotor, VehicleState
from plant_sim.world import World
from protocols.camera import CameraModel
from protocols.config import Checked, bounded
from protocols.stereo_frame import DepthFrame, StereoFrame

__all__ = [
    "HOLD_REST_S",
    "HOLD_REST_SPEED_MPS",
    "KillOutcome",
    "RunConfig",
    "RunResult",
    "Verdict",
    "nearest_surface_m",
    "run_scene",
]


#: A run ends in a reported stop once the vehicle, in guidance's HOLD, has been slower than
#: HOLD_REST_SPEED_MPS for HOLD_REST_S of simulation time (lockstep and SIL judge alike).
HOLD_REST_SPEED_MPS = 0.05
HOLD_REST_S = 2.0


@dataclass(frozen=True)
class RunConfig(Checked):
    """How a lockstep run is set up and judged."""

    camera_rate_hz: float = bounded(30.0, "Hz", gt=0)
    # simulation time before the run is declared a timeout
    max_time_s: float = bounded(90.0, "s", gt=0)
    goal_tolerance_m: float = bounded(0.5, "m", gt=0)  # §6 test: goal reached within 0.5 m
    # Collision: the body touching a surface, i.e. the vehicle centre nearer the true
    # surface than its radius with propellers (arm d = 0.25 m of Table 2 plus a rotor:
    # 0.35 m, the radius perception inflates boundaries by)
    collision_distance_m: float = bounded(0.35, "m", ge=0)
    camera: CameraModel = field(default_factory=CameraModel)
    render: RenderParams = field(default_factory=RenderParams)
    perception: PerceptionConfig = field(default_factory=PerceptionConfig)
    guidance: GuidanceConfig = field(default_factory=GuidanceConfig)
    known_space: KnownSpaceConfig = field(default_factory=KnownSpaceConfig)
    envelope: EnvelopeConfig = field(default_factory=EnvelopeConfig)
    vehicle: QuadrotorParams = field(default_factory=QuadrotorParams)
    control: ControlParams = field(default_factory=ControlParams)
    # The companion's death (SIGKILL) in lockstep: from this simulation time on, no frame
    # is processed and the autopilot keeps tracking the last setpoint; the run ends once
    # the vehicle has stopped (speed below 0.05 m/s for 1 s) or at max_time_s.
    companion_stop_s: float | None = bounded(None, "s", ge=0, optional=True)
    # Ground-truth perception: the renderer's exact depth instead of the stereo matcher
    # (evaluation.truth_perception); guidance, envelope and known space unchanged.
    truth_perception: bool = False
    # A RealSense-like depth camera instead of the stereo pair (issue 35): depth frames
    # (plant_sim.depth_camera) with these errors; the companion runs no matcher.
    camera_encoding: CameraEncoding = CameraEncoding.MONO8
    depth_noise: DepthNoiseParams = field(default_factory=DepthNoiseParams)
    # plant-sim's ArduCopter between the companion and the LQ loop (issue 31): its tick
    # rate [Hz of simulation time], its parameters (ArduCopter names and units, e.g.
    # {"WPNAV_SPEED": 100.0}) and whether the companion states the envelope's speed limit
    # with DO_CHANGE_SPEED, as it does to ArduPilot (False: the carrot alone bounds it)
    autopilot_rate_hz: float = bounded(50.0, "Hz", gt=0)
    autopilot_params: Mapping[str, float] = field(default_factory=dict)
    state_speed_limit: bool = True


@dataclass(frozen=True)
class Verdict:
    """The outcome of a run (the JSON verdict of ``stereo-avoid paper``)."""

    scene: str
    seed: int
    reached_goal: bool
    collided: bool
    min_surface_distance_m: float
    max_roll_cmd_deg: float
    max_pitch_cmd_deg: float
    avoidance_time_s: float
    sim_time_s: float
    wall_time_s: float
    final_goal_distance_m: float
    frames: int
    # None, "collision", "timeout", "hold" (stopped: no free direction), "companion_stopped"
    failure: str | None
    hold_reason: str | None = None  # guidance's reason when the run ended in a HOLD
    # frames on which the companion's overspeed warning would fire: measured speed above
    # the envelope's stated limit by more than its tolerance (CompanionCore._check_overspeed)
    overspeed_frames: int = 0
    # frames whose target (carrot or hold) lay inside one of the boundaries guidance had
    # that frame (invariant 3 of the envelope: never)
    targets_inside_boundary: int = 0

    @property
    def passed(self) -> bool:
        """Goal reached without a collision."""
        return self.reached_goal and not self.collided

    @property
    def safe_stop(self) -> bool:
        """Not at the goal, but stopped where guidance reported a hold, without a collision
        (a goal inside an obstacle, no free direction, no progress): a safe outcome."""
        return not self.reached_goal and not self.collided and self.failure == "hold"

    @property
    def outcome(self) -> str:
        """``PASS`` (goal reached), ``SAFE STOP (reason)`` or ``FAIL (cause)``."""
        if self.passed:
            return "PASS"
        if self.safe_stop:
            return f"SAFE STOP ({self.hold_reason})"
        return f"FAIL ({self.failure or 'goal not reached'})"


@dataclass(frozen=True, eq=False)
class RunResult:
    """A verdict with the time history behind it (and the companion-death tails)."""

    verdict: Verdict
    history: History
    kills: tuple[KillOutcome, ...] = ()


@dataclass(frozen=True)
class KillOutcome:
    """What the vehicle did after the companion died at ``stop_s`` (SIGKILL in lockstep).

    The autopilot keeps tracking the last setpoint the companion sent; the tail is flown
    on a copy of the plant until the vehicle has stopped (speed < 0.05 m/s for 1 s).
    """

    stop_s: float
    min_surface_distance_m: float
    stopped: bool
    end_time_s: float
    end_pos_ned_m: tuple[float, float, float]
    last_setpoint_ned_m: tuple[float, float, float]
    max_speed_mps: float


_PROXIMITY = ProximityConfig()  # the companion's default OBSTACLE_DISTANCE layout


def nearest_surface_m(world: World, pos_ned_m: np.ndarray) -> float:
    """Distance from ``pos_ned_m`` to the nearest obstacle surface of any shape [m] (negative
    inside); inf with none."""
    return world.surface_distance_m(pos_ned_m)


def run_scene(
    scene: Scene,
    config: RunConfig | None = None,
    *,
    progress: Callable[[float, float], None] | None = None,
    kill_times_s: Sequence[float] = (),
    record_history: bool = True,
    on_step: Callable[[StereoFrame, PoseAtCapture, MissionStep, Mission], None] | None = None,
) -> RunResult:
    """Fly ``scene`` in lockstep until the goal, a collision or ``max_time_s``.

    Parameters
    ----------
    progress : callable(sim_time_s, goal_distance_m), optional
        Called about once per simulated second.
    kill_times_s : sequence of float
        Simulation times at which to also simulate the companion's death: at the first
        frame at or after each, a copy of the plant flies on with the last setpoint
        (:class:`KillOutcome` in ``RunResult.kills``) while the run itself continues.
    record_history : bool
        Keep the per-frame time history (figures, CSV); False leaves ``RunResult.history``
        empty (Monte Carlo keeps only the verdict).
    on_step : callable(frame, pose, step, mission), optional
        Called after every mission step (a Rerun view, :mod:`evaluation.view`);
        ``pose`` is the plant's true pose at capture.
    """
    cfg = config or RunConfig()
    wall_start = time.perf_counter()
    quad, mission, autopilot = _start(scene, cfg)
    shoot = _camera(scene, cfg, mission)
    centres_ned_m = np.array([s.center_ned_m for s in scene.world.spheres]).reshape(-1, 3)
    radii_m = np.array([s.radius_m for s in scene.world.spheres])
    goal = np.asarray(scene.goal_ned_m, dtype=float)
    history = History()
    frame_period_s = 1.0 / cfg.camera_rate_hz
    tally = _Tally()
    seq = 0
    next_progress_s = 0.0
    pending_kills = sorted(float(t) for t in kill_times_s)
    kills: list[KillOutcome] = []
    disturbed = _disturbances(scene)
    while True:
        state = quad.snapshot()
        error_ned_m = _disturb(disturbed, quad, state.time_s)
        pose = PoseAtCapture(
            state.pos_ned_m + error_ned_m,
            state.vel_ned_mps,
            state.R_ned_from_frd,
            h_acc_m=_stated_h_acc_m(disturbed),
        )
        frame = shoot(state, seq)
        surface = nearest_surface_m(scene.world, state.pos_ned_m)
        history.settle_proximity(surface)  # before the step changes the map it reads
        step = mission.step(frame, pose)
        if on_step is not None:
            on_step(frame, pose, step, mission)
        out = step.output
        autopilot.command_output(out, state.time_s)
        if record_history:
            _record(history, state, surface, out, len(out.perception.obstacles), mission)
        tally.note_frame(out, surface, frame_period_s)
        if progress is not None and state.time_s >= next_progress_s:
            progress(state.time_s, math.dist(state.pos_ned_m, goal))
            next_progress_s += 1.0
        while pending_kills and state.time_s >= pending_kills[0] - 1e-9:
            flown = copy.deepcopy((quad, autopilot, disturbed))
            kills.append(_kill_tail(*flown, scene.world, pending_kills.pop(0), cfg))
        if tally.ends_run(cfg, mission, out.guidance, state, surface):
            break
        if cfg.companion_stop_s is not None and state.time_s >= cfg.companion_stop_s:
            tail = _kill_tail(quad, autopilot, disturbed, scene.world, state.time_s, cfg)
            tally.companion_stops(tail, quad, goal, cfg)
            break
        seq += 1
        end_step = quad_step(quad) + _steps_until(quad, seq * frame_period_s)
        _fly_until(end_step, quad, autopilot, disturbed, (centres_ned_m, radii_m), tally)
    verdict = tally.verdict(scene, quad, goal, frames=seq + 1, wall_start_s=wall_start)
    return RunResult(verdict=verdict, history=history, kills=tuple(kills))


def _fly_until(
    end_step: int,
    quad: Quadrotor,
    autopilot: LockstepAutopilot,
    disturbed: Disturbances | None,
    spheres: tuple[np.ndarray, np.ndarray],
    tally: _Tally,
) -> None:
    """Advance the plant to physics step ``end_step`` (the next frame) through the
    autopilot's ticks, watching commanded tilt and clearance at every step."""
    while True:
        tick_step = autopilot.next_tick_step()
        if tick_step < end_step and tick_step <= quad_step(quad):  # due (never skipped)
            autopilot.tick(quad, _disturb(disturbed, quad, quad.time_s))
            continue
        n_steps = min(end_step, tick_step) - quad_step(quad)
        if n_steps <= 0:
            return
        roll_cmd, pitch_cmd, surface_min = quad.step_watching(n_steps, *spheres)
        tally.max_roll = max(tally.max_roll, roll_cmd)
        tally.max_pitch = max(tally.max_pitch, pitch_cmd)
        tally.min_surface = min(tally.min_surface, surface_min)


def _disturbances(scene: Scene) -> Disturbances | None:
    d = scene.disturbance
    return Disturbances(d) if d is not None and d.active else None


def _disturb(disturbed: Disturbances | None, quad: Quadrotor, time_s: float) -> np.ndarray:
    """Advance the wind and the estimate error to ``time_s``; the wind goes on the
    physics (until the next frame), the estimate error [m, NED] is returned."""
    if disturbed is None:
        return _NO_ERROR
    disturbed.advance(time_s)
    quad.set_wind_ned_mps(disturbed.wind_ned_mps)
    return np.asarray(disturbed.estimate_error_ned_m)


def _stated_h_acc_m(disturbed: Disturbances | None) -> float | None:
    """The horizontal accuracy plant-sim's autopilot states (GPS_RAW_INT ``h_acc``), as
    the companion reads it; None without a disturbance (h_acc 0: none stated)."""
    return None if disturbed is None else disturbed.stated_accuracy_m[0]


_NO_ERROR = np.zeros(3)
_NO_ERROR.flags.writeable = False


def quad_step(quad: Quadrotor) -> int:
    """The plant's physics step count (its clock in whole steps)."""
    return round(quad.time_s / quad.dt_s)


def _start(scene: Scene, cfg: RunConfig) -> tuple[Quadrotor, Mission, LockstepAutopilot]:
    """The plant at the scene's start, its autopilot in GUIDED and the companion's mission
    to its waypoints."""
    ground_down_m = None if scene.world.ground is None else scene.world.ground.down_m
    quad = Quadrotor(
        cfg.vehicle,
        cfg.control,
        pos_ned_m=scene.start_ned_m,
        yaw_rad=scene.start_yaw_rad,
        ground_down_m=ground_down_m,
    )
    autopilot = LockstepAutopilot(
        quad,
        autopilot_params(cfg.control.max_tilt_deg, cfg.autopilot_params),
        ground_down_m=ground_down_m,
        rate_hz=cfg.autopilot_rate_hz,
        state_speed_limit=cfg.state_speed_limit,
    )
    mission = Mission(
        scene.waypoints_ned_m,
        cfg.goal_tolerance_m,
        cfg.perception,
        cfg.guidance,
        cfg.known_space,
        cfg.envelope,
        depth_source=TruthDepthSource(cfg.perception) if cfg.truth_perception else None,
    )
    return quad, mission, autopilot


def _camera(
    scene: Scene, cfg: RunConfig, mission: Mission
) -> Callable[[VehicleState, int], StereoFrame]:
    """What the companion is shown at a state: the rendered stereo pair, or with ground-truth
    perception blank images whose true depth the mission's depth source (the
    :class:`TruthDepthSource` of :func:`_start`) is handed."""
    renderer = StereoCameraRenderer(cfg.camera, cfg.render)
    intrinsics = cfg.camera.intrinsics
    if cfg.camera_encoding is not CameraEncoding.MONO8 and not cfg.truth_perception:

        def depth_camera(state: VehicleState, seq: int) -> DepthFrame:
            render = renderer.render(
                scene.world, state.pos_ned_m, state.R_ned_from_frd, noise_seed=seq
            )
            capture_ns = round(state.time_s * 1e9)
            return depth_frame(
                seq,
                capture_ns,
                intrinsics,
                render.depth_left_m,
                render.left,
                cfg.depth_noise,
                cfg.camera_encoding,
            )

        return depth_camera
    if not cfg.truth_perception:
        return lambda state, seq: _render_frame(
            renderer, scene.world, state, state.R_ned_from_frd, seq, intrinsics
        )
    truth = mission.pipeline.perception.source
    if not isinstance(truth, TruthDepthSource):
        raise TypeError(f"ground truth needs a TruthDepthSource, the mission has {truth!r}")
    blank = np.zeros((intrinsics.height_px, intrinsics.width_px), np.uint8)
    blank.flags.writeable = False

    def shoot(state: VehicleState, seq: int) -> StereoFrame:
        truth.provide(
            seq, renderer.render_depth(scene.world, state.pos_ned_m, state.R_ned_from_frd)
        )
        return StereoFrame(seq, round(state.time_s * 1e9), intrinsics, blank, blank)

    return shoot


@dataclass
class _Tally:
    """What a run has measured so far, and how it ended."""

    min_surface: float = math.inf
    max_roll: float = 0.0
    max_pitch: float = 0.0
    avoid_time: float = 0.0
    hold_since: float | None = None
    reached: bool = False
    collided: bool = False
    failure: str | None = None
    hold_reason: str | None = None
    overspeed_frames: int = 0
    targets_inside_boundary: int = 0

    def note_frame(self, out, surface_m: float, frame_period_s: float) -> None:
        """What one frame's output and the true clearance add to the tally."""
        self.overspeed_frames += bool(out.envelope.overspeed)
        self.targets_inside_boundary += inside_any(out.setpoint_ned_m, out.boundaries)
        self.min_surface = min(self.min_surface, surface_m)
        if out.guidance.avoidance_flag:
            self.avoid_time += frame_period_s

    def ends_run(self, cfg: RunConfig, mission: Mission, decision, state, surface: float) -> bool:
        """A collision, the goal, a reported stop come to rest for 2 s (the world is static)
        or the time limit ends the run."""
        if surface < cfg.collision_distance_m:
            self.collided, self.failure = True, "collision"
            return True
        if mission.goal_reached:  # the last waypoint, within goal_tolerance_m
            self.reached = True
            return True
        speed = float(np.linalg.norm(state.vel_ned_mps))
        if decision.mode is Mode.HOLD and speed < HOLD_REST_SPEED_MPS:
            self.hold_since = state.time_s if self.hold_since is None else self.hold_since
            if state.time_s - self.hold_since >= HOLD_REST_S:
                self.failure, self.hold_reason = "hold", decision.reason.value
                return True
        else:
            self.hold_since = None
        if state.time_s >= cfg.max_time_s:
            self.failure = "hold" if decision.mode is Mode.HOLD else "timeout"
            self.hold_reason = decision.reason.value if self.failure == "hold" else None
            return True
        return False

    def companion_stops(self, tail: KillOutcome, quad: Quadrotor, goal, cfg: RunConfig) -> None:
        """The run ends with the companion's death: judged by how the plant flew on."""
        self.min_surface = min(self.min_surface, tail.min_surface_distance_m)
        self.reached = float(np.linalg.norm(quad.pos_ned_m - goal)) < cfg.goal_tolerance_m
        self.collided = self.min_surface < cfg.collision_distance_m
        self.failure = "collision" if self.collided else "companion_stopped"

    def verdict(self, scene: Scene, quad: Quadrotor, goal, *, frames: int, wall_start_s: float):
        return Verdict(
            scene=scene.name,
            seed=scene.seed,
            reached_goal=self.reached,
            collided=self.collided,
            min_surface_distance_m=round(self.min_surface, 4),
            max_roll_cmd_deg=round(math.degrees(self.max_roll), 4),
            max_pitch_cmd_deg=round(math.degrees(self.max_pitch), 4),
            avoidance_time_s=round(self.avoid_time, 4),
            sim_time_s=round(quad.time_s, 4),
            wall_time_s=round(time.perf_counter() - wall_start_s, 3),
            final_goal_distance_m=round(float(np.linalg.norm(quad.pos_ned_m - goal)), 4),
            frames=frames,
            failure=self.failure,
            hold_reason=self.hold_reason,
            overspeed_frames=self.overspeed_frames,
            targets_inside_boundary=self.targets_inside_boundary,
        )


def _steps_until(quad: Quadrotor, time_s: float) -> int:
    """Physics steps, in whole control periods, until the plant's clock reaches ``time_s``."""
    dt_s, per = quad.dt_s, quad.control.steps_per_control
    done = round(quad.time_s / dt_s)
    n = 0
    while (done + n) * dt_s < time_s - 1e-12:
        n += per
    return n


def _kill_tail(
    quad: Quadrotor,
    autopilot: LockstepAutopilot,
    disturbed: Disturbances | None,
    world: World,
    stop_s: float,
    cfg: RunConfig,
) -> KillOutcome:
    """Fly ``quad`` (a copy) with no further command: its autopilot keeps flying the last
    target it was sent, until the vehicle stops; see :class:`KillOutcome`."""
    setpoint = autopilot.last_target_ned_m
    min_surface = nearest_surface_m(world, quad.pos_ned_m)
    max_speed = 0.0
    still_since: float | None = None
    stopped = False
    t_end = quad.time_s + 60.0
    while quad.time_s < t_end:
        n = autopilot.next_tick_step() - quad_step(quad)
        if n <= 0:
            autopilot.tick(quad, _disturb(disturbed, quad, quad.time_s))
            continue
        quad.step(n)
        min_surface = min(min_surface, nearest_surface_m(world, quad.pos_ned_m))
        speed = float(np.linalg.norm(quad.vel_ned_mps))
        max_speed = max(max_speed, speed)
        if min_surface < cfg.collision_distance_m:
            break
        if speed < 0.05:
            still_since = quad.time_s if still_since is None else still_since
            if quad.time_s - still_since >= 1.0:
                stopped = True
                break
        else:
            still_since = None
    return KillOutcome(
        stop_s=stop_s,
        min_surface_distance_m=round(min_surface, 4),
        stopped=stopped,
        end_time_s=round(quad.time_s, 4),
        end_pos_ned_m=tuple(round(float(x), 4) for x in quad.pos_ned_m),
        last_setpoint_ned_m=tuple(float(x) for x in setpoint),
        max_speed_mps=round(max_speed, 4),
    )


def _render_frame(
    renderer: StereoCameraRenderer,
    world: World,
    state: VehicleState,
    R_ned_from_frd: np.ndarray,
    seq: int,
    intrinsics,
) -> StereoFrame:
    render = renderer.render(world, state.pos_ned_m, R_ned_from_frd, noise_seed=seq)
    return StereoFrame(
        sequence=seq,
        capture_ns=round(state.time_s * 1e9),
        intrinsics=intrinsics,
        left=render.left,
        right=render.right,
    )


def _record(
    history: History, s: VehicleState, surface_m: float, out, n_seen: int, mission: Mission
) -> None:
    history.note_proximity(  # what OBSTACLE_DISTANCE says at the closest approach
        surface_m,
        functools.partial(
            sectors_from_map, mission.pipeline.known_space, s.pos_ned_m, s.yaw_rad, _PROXIMITY
        ),
    )
    decision = out.guidance
    sp = out.setpoint_ned_m
    history.append(
        time_s=s.time_s,
        north_m=s.pos_ned_m[0],
        east_m=s.pos_ned_m[1],
        down_m=s.pos_ned_m[2],
        vn_mps=s.vel_ned_mps[0],
        ve_mps=s.vel_ned_mps[1],
        vd_mps=s.vel_ned_mps[2],
        roll_deg=math.degrees(s.roll_rad),
        pitch_deg=math.degrees(s.pitch_rad),
        yaw_deg=math.degrees(s.yaw_rad),
        roll_cmd_deg=math.degrees(s.roll_cmd_rad),
        pitch_cmd_deg=math.degrees(s.pitch_cmd_rad),
        yaw_cmd_deg=math.degrees(s.yaw_cmd_rad),
        rotor1_n=s.rotor_thrusts_n[0],
        rotor2_n=s.rotor_thrusts_n[1],
        rotor3_n=s.rotor_thrusts_n[2],
        rotor4_n=s.rotor_thrusts_n[3],
        nearest_surface_m=surface_m,
        avoid_flag=1.0 if decision.avoidance_flag else 0.0,
        mode=list(Mode).index(decision.mode),
        setpoint_north_m=sp[0],
        setpoint_east_m=sp[1],
        setpoint_down_m=sp[2],
        n_obstacles_seen=n_seen,
        tilt_saturated=1.0 if s.tilt_saturated else 0.0,
        free_distance_m=out.envelope.free_distance_m,
        speed_limit_mps=out.envelope.speed_limit_mps,
        speed_mps=out.envelope.speed_mps,
    )
