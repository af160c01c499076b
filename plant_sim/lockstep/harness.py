"""Lockstep run: plant + synthetic stereo camera + the companion's pipeline, one process.

Deterministic in simulation time and free of sockets: each camera period the plant is
advanced, the stereo pair rendered at the true pose, the companion's
:class:`~companion.pipeline.AvoidancePipeline` (the same code the networked companion
runs) turns it into a setpoint, and the plant tracks that setpoint until the next frame.
The pose handed to the pipeline is the plant's at the frame's capture time, as the
networked companion interpolates it from telemetry.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from companion.guidance import GuidanceConfig, Mode
from companion.perception import PerceptionConfig
from companion.pipeline import AvoidancePipeline, PoseAtCapture
from plant_sim.lockstep.history import History
from plant_sim.lockstep.scenes import Scene
from plant_sim.params import ControlParams, QuadrotorParams
from plant_sim.stereo_camera import RenderParams, StereoCameraRenderer
from plant_sim.vehicle import Quadrotor, Setpoint, VehicleState
from plant_sim.world import World
from protocols.camera import CameraModel
from protocols.stereo_frame import StereoFrame

__all__ = ["RunConfig", "RunResult", "Verdict", "nearest_surface_m", "run_scene"]


@dataclass(frozen=True)
class RunConfig:
    """How a lockstep run is set up and judged."""

    camera_rate_hz: float = 30.0
    max_time_s: float = 90.0  # simulation time before the run is declared a timeout
    goal_tolerance_m: float = 0.5  # §6 test: goal reached within 0.5 m
    # Collision: vehicle centre nearer the true surface than the arm length d (Table 2).
    collision_distance_m: float = 0.25
    camera: CameraModel = field(default_factory=CameraModel)
    render: RenderParams = field(default_factory=RenderParams)
    perception: PerceptionConfig = field(default_factory=PerceptionConfig)
    guidance: GuidanceConfig = field(default_factory=GuidanceConfig)
    vehicle: QuadrotorParams = field(default_factory=QuadrotorParams)
    control: ControlParams = field(default_factory=ControlParams)

    def __post_init__(self) -> None:
        for name in ("camera_rate_hz", "max_time_s", "goal_tolerance_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be finite and positive, got {value!r}")


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
    failure: str | None  # None, "collision", "timeout", "hold" (stopped: no free direction)

    @property
    def passed(self) -> bool:
        """Goal reached without a collision."""
        return self.reached_goal and not self.collided


@dataclass(frozen=True, eq=False)
class RunResult:
    """A verdict with the time history behind it."""

    verdict: Verdict
    history: History


def nearest_surface_m(world: World, pos_ned_m: np.ndarray) -> float:
    """Distance from ``pos_ned_m`` to the nearest sphere surface [m]; inf with none."""
    if not world.spheres:
        return math.inf
    return min(s.surface_distance_m(pos_ned_m) for s in world.spheres)


def run_scene(
    scene: Scene,
    config: RunConfig | None = None,
    *,
    progress: Callable[[float, float], None] | None = None,
) -> RunResult:
    """Fly ``scene`` in lockstep until the goal, a collision or ``max_time_s``.

    Parameters
    ----------
    progress : callable(sim_time_s, goal_distance_m), optional
        Called about once per simulated second.
    """
    cfg = config or RunConfig()
    wall_start = time.perf_counter()
    quad = Quadrotor(
        cfg.vehicle,
        cfg.control,
        pos_ned_m=scene.start_ned_m,
        yaw_rad=scene.start_yaw_rad,
        ground_down_m=None if scene.world.ground is None else scene.world.ground.down_m,
    )
    renderer = StereoCameraRenderer(cfg.camera, cfg.render)
    intrinsics = cfg.camera.intrinsics
    pipeline = AvoidancePipeline(scene.goal_ned_m, cfg.perception, cfg.guidance)
    goal = np.asarray(scene.goal_ned_m, dtype=float)
    history = History()
    frame_period_s = 1.0 / cfg.camera_rate_hz

    min_surface = math.inf
    max_roll = max_pitch = 0.0
    avoid_time = 0.0
    reached = collided = False
    failure: str | None = None
    seq = 0
    next_progress_s = 0.0
    while True:
        state = quad.snapshot()
        frame = _render_frame(renderer, scene.world, state, seq, intrinsics)
        pose = PoseAtCapture(state.pos_ned_m, state.vel_ned_mps, state.R_ned_from_frd)
        out = pipeline.process(frame, pose)
        decision = out.guidance
        quad.set_setpoint(Setpoint(pos_ned_m=tuple(out.setpoint_ned_m), yaw_rad=out.yaw_rad))
        surface = nearest_surface_m(scene.world, state.pos_ned_m)
        goal_dist = float(np.linalg.norm(state.pos_ned_m - goal))
        _record(history, state, surface, out, len(out.perception.obstacles))
        min_surface = min(min_surface, surface)
        if decision.avoidance_flag:
            avoid_time += frame_period_s
        if progress is not None and state.time_s >= next_progress_s:
            progress(state.time_s, goal_dist)
            next_progress_s += 1.0
        if surface < cfg.collision_distance_m:
            collided, failure = True, "collision"
            break
        if goal_dist < cfg.goal_tolerance_m:
            reached = True
            break
        if state.time_s >= cfg.max_time_s:
            failure = "hold" if decision.mode is Mode.HOLD else "timeout"
            break
        # advance to the next frame, watching commanded tilt and clearance at control rate
        seq += 1
        t_next = seq * frame_period_s
        while quad.time_s < t_next - 1e-12:
            quad.step(quad.control.steps_per_control)
            roll_cmd, pitch_cmd = quad.tilt_cmd_rad()
            max_roll = max(max_roll, abs(roll_cmd))
            max_pitch = max(max_pitch, abs(pitch_cmd))
            min_surface = min(min_surface, nearest_surface_m(scene.world, quad.pos_ned_m))

    verdict = Verdict(
        scene=scene.name,
        seed=scene.seed,
        reached_goal=reached,
        collided=collided,
        min_surface_distance_m=round(min_surface, 4),
        max_roll_cmd_deg=round(math.degrees(max_roll), 4),
        max_pitch_cmd_deg=round(math.degrees(max_pitch), 4),
        avoidance_time_s=round(avoid_time, 4),
        sim_time_s=round(quad.time_s, 4),
        wall_time_s=round(time.perf_counter() - wall_start, 3),
        final_goal_distance_m=round(float(np.linalg.norm(quad.pos_ned_m - goal)), 4),
        frames=seq + 1,
        failure=failure,
    )
    return RunResult(verdict=verdict, history=history)


def _render_frame(
    renderer: StereoCameraRenderer, world: World, state: VehicleState, seq: int, intrinsics
) -> StereoFrame:
    render = renderer.render(world, state.pos_ned_m, state.R_ned_from_frd, noise_seed=seq)
    return StereoFrame(
        sequence=seq,
        capture_ns=round(state.time_s * 1e9),
        intrinsics=intrinsics,
        left=render.left,
        right=render.right,
    )


def _record(history: History, s: VehicleState, surface_m: float, out, n_seen: int) -> None:
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
