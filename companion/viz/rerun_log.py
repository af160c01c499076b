"""Rerun logging of what the companion sees and decides (``--rerun FILE.rrd|serve``).

:class:`RerunLogger` turns one pipeline step into Rerun entities on the ``capture_time``
timeline (the frame's capture time: simulation time in the SIL and lockstep, this host's
monotonic clock with a real camera). The world is LOCAL_NED (``world`` has view
coordinates FRD = north, east, down).

=================================  ==========================================================
entity                             what
=================================  ==========================================================
``world/vehicle``                  pose at capture (Transform3D, body FRD) and its axes
``world/vehicle/camera``           the left camera (Pinhole, optical frame RDF): the frustum
                                   in 3-D, and the 2-D views
``.../camera/image``               left image
``.../camera/depth``               depth [mm] (DepthImage; unmatched and beyond range: 0)
``.../camera/classes``             near (red) and unknown (grey) masks (SegmentationImage)
``world/trail``                    the vehicle's path so far
``world/velocity``                 velocity arrow [m/s drawn as m over 1 s]
``world/obstacle_points``          obstacle pixels (depth < threshold) back-projected
``world/boundaries``               boundary spheres seen in this frame (perception)
``world/tracks``                   remembered spheres (guidance memory); red when active
``world/cones``                    collision cones of the tracks; red when critical
``world/aiming_point``             Eq. (28) aiming point, while avoiding
``world/setpoint``                 the carrot sent to the autopilot (safety envelope)
``world/goal``                     the current goal
``world/known_space``              occupied voxels of the known-space model
``world/truth/...``                ground truth where the simulator knows it
``status/...``                     avoidance flag, mode, speed, speed limit, free distance
=================================  ==========================================================

:class:`RerunObserver` is the companion's observer (:mod:`companion.observe`): for each
:class:`~companion.core.events.FrameProcessed` the core returns, it only queues references
to the frame and the pipeline output, at most ``rate_hz`` (10) frames a second of capture
time; a thread of its own logs them, so the per-frame latency of the service barely moves
(``benchmarks/bench_view.py``). The known-space voxels are read on that thread, so they may
be a frame newer than the rest (drawn every ``known_space_every`` logged frames).
"""

from __future__ import annotations

import logging
import queue
import threading
from collections import deque
from pathlib import Path

import numpy as np

from companion.core.events import FrameProcessed
from companion.observe import CompanionObserver
from companion.viz.scene_geometry import (
    CLASS_NEAR,
    CLASS_UNKNOWN,
    CLASS_VALID,
    cone_lines_ned_m,
    depth_classes,
    near_points_ned_m,
    velocity_in_cone,
)
from protocols.stereo_frame import StereoFrame

__all__ = ["RerunLogger", "RerunObserver", "RerunTarget", "blueprint", "open_stream"]

_log = logging.getLogger("companion.viz")

TIMELINE = "capture_time"
_CAM = "world/vehicle/camera"  # the left camera: pinhole, image, depth, masks
_RED = (230, 40, 40)
_ORANGE = (255, 150, 30)
_GREEN = (40, 200, 80)
_BLUE = (60, 120, 255)
_GREY = (150, 150, 150)
# body FRD → left camera optical frame RDF (x right, y down, z forward): columns are the
# optical axes in body coordinates
_R_FRD_FROM_RDF = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


class RerunTarget:
    """Where a recording goes: a ``.rrd`` file or a local web viewer."""

    def __init__(self, path: Path | None = None, web_port: int | None = None, grpc_port=None):
        if (path is None) == (web_port is None):
            raise ValueError("give a .rrd path or a web port")
        self.path = path
        self.web_port = web_port
        self.grpc_port = grpc_port

    @classmethod
    def parse(cls, text: str) -> RerunTarget:
        """``FILE.rrd`` or ``serve`` / ``serve:PORT`` (web viewer port; gRPC: PORT + 1)."""
        if text == "serve" or text.startswith("serve:"):
            port_text = text.partition(":")[2] or "9090"
            try:
                port = int(port_text)
            except ValueError:
                raise ValueError(f"--rerun serve:PORT needs a port number, got {text!r}") from None
            if not 1 <= port <= 65534:
                raise ValueError(f"--rerun serve:PORT must be 1..65534, got {port}")
            return cls(web_port=port, grpc_port=port + 1)
        path = Path(text)
        if path.suffix != ".rrd":
            raise ValueError(f"--rerun takes FILE.rrd or serve[:PORT], got {text!r}")
        return cls(path=path)

    def describe(self) -> str:
        if self.path is not None:
            return str(self.path)
        return f"http://127.0.0.1:{self.web_port} (gRPC {self.grpc_port})"


def blueprint():
    """The default layout: 3-D scene left; left image, depth and masks, status right."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(
                name="3-D (NED)",
                origin="world",
                # the depth map under the pinhole would also be drawn as a 3-D point cloud
                contents=["+ world/**", f"- {_CAM}/depth", f"- {_CAM}/classes"],
            ),
            rrb.Vertical(
                rrb.Spatial2DView(
                    name="left image, near (red) and unknown (grey)",
                    origin=_CAM,
                    contents=[f"{_CAM}/image", f"{_CAM}/classes"],
                ),
                rrb.Spatial2DView(name="depth [m]", origin=_CAM, contents=[f"{_CAM}/depth"]),
                rrb.TimeSeriesView(name="status", origin="status"),
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


def open_stream(target: RerunTarget, application_id: str = "stereo_avoid"):
    """A Rerun recording stream on ``target`` (the web viewer is started here)."""
    import rerun as rr

    rec = rr.RecordingStream(application_id)
    if target.path is not None:
        target.path.parent.mkdir(parents=True, exist_ok=True)
        rec.save(target.path, default_blueprint=blueprint())
    else:
        url = rec.serve_grpc(grpc_port=target.grpc_port, default_blueprint=blueprint())
        rr.serve_web_viewer(web_port=target.web_port, open_browser=False, connect_to=url)
    return rec


class RerunLogger:
    """Logs pipeline steps to a Rerun recording stream (see the module docstring).

    Parameters
    ----------
    rec : rerun.RecordingStream
    threshold_m : detection threshold (the near mask) [m].
    trail_len : positions kept in the trail.
    trail_every : the trail is re-logged every this many steps (it grows with the run).
    """

    def __init__(
        self, rec, threshold_m: float, trail_len: int = 2000, trail_every: int = 10
    ) -> None:
        import rerun as rr

        self.rr = rr
        self.rec = rec
        self.threshold_m = float(threshold_m)
        self._trail: deque = deque(maxlen=trail_len)
        self._true_trail: deque = deque(maxlen=trail_len)
        self._static_logged = False
        self.trail_every = trail_every
        self._steps = 0

    def _static(self, frame: StereoFrame) -> None:
        rr, rec = self.rr, self.rec
        rec.log("world", rr.ViewCoordinates.FRD, static=True)
        rec.log("world/vehicle", rr.TransformAxes3D(0.6), static=True)
        rec.log(
            _CAM,
            rr.AnnotationContext(
                [
                    (CLASS_VALID, "matched, beyond the threshold", (0, 0, 0, 0)),
                    (CLASS_NEAR, "near (obstacle)", (*_RED, 160)),
                    (CLASS_UNKNOWN, "unknown (no match)", (*_GREY, 120)),
                ]
            ),
            static=True,
        )
        k = frame.intrinsics
        rec.log(
            _CAM,
            rr.Transform3D(translation=[0.0, -k.baseline_m / 2.0, 0.0], mat3x3=_R_FRD_FROM_RDF),
            rr.Pinhole(
                focal_length=[k.fx_px, k.fy_px],
                principal_point=[k.cx_px, k.cy_px],
                width=k.width_px,
                height=k.height_px,
                camera_xyz=rr.ViewCoordinates.RDF,
                image_plane_distance=1.0,
            ),
            static=True,
        )
        self._static_logged = True

    def log_truth_world(self, world) -> None:
        """Ground-truth obstacles of a simulated world (plant_sim.world.World), static."""
        rr, rec = self.rr, self.rec
        if world.spheres:
            rec.log(
                "world/truth/spheres",
                rr.Ellipsoids3D(
                    centers=[s.center_ned_m for s in world.spheres],
                    half_sizes=[[s.radius_m] * 3 for s in world.spheres],
                    colors=[(*_GREY, 255)],
                    fill_mode="solid",
                ),
                static=True,
            )
        boxes = getattr(world, "boxes", ())
        if boxes:
            rec.log(
                "world/truth/boxes",
                rr.Boxes3D(
                    mins=[b.min_ned_m for b in boxes],
                    sizes=[np.subtract(b.max_ned_m, b.min_ned_m) for b in boxes],
                    colors=[(*_GREY, 255)],
                    fill_mode="solid",
                ),
                static=True,
            )

    def log_truth_pose(self, capture_ns: int, pos_ned_m) -> None:
        """Where the simulator says the vehicle is at ``capture_ns``."""
        self.rec.set_time(TIMELINE, duration=capture_ns * 1e-9)
        self._true_trail.append([float(x) for x in pos_ned_m])
        if len(self._true_trail) >= 2 and len(self._true_trail) % self.trail_every == 0:
            self.rec.log(
                "world/truth/trail",
                self.rr.LineStrips3D([list(self._true_trail)], colors=[_GREY], radii=[0.02]),
            )

    def log_step(
        self, frame: StereoFrame, pose, out, *, goal_ned_m=None, known_space=None, heavy=True
    ):
        """One pipeline step: ``frame`` with ``pose`` (PoseAtCapture) gave ``out``.

        ``heavy=False`` leaves out the images, depth, masks, obstacle points and known
        space (the pose, spheres, cones, setpoints and status are always logged)."""
        rr, rec = self.rr, self.rec
        if not self._static_logged:
            self._static(frame)
        rec.set_time(TIMELINE, duration=frame.capture_ns * 1e-9)
        pos = np.asarray(pose.pos_ned_m, dtype=float)
        vel = np.asarray(pose.vel_ned_mps, dtype=float)
        R = np.asarray(pose.R_ned_from_frd, dtype=float)
        self._log_vehicle(pos, vel, R)
        if heavy:
            self._log_images(frame, out.perception.depth_m, pos, R)
        obstacles = out.obstacles  # the map's boundaries: what guidance steers on
        rec.log(
            "world/boundaries",
            rr.Ellipsoids3D(
                centers=[np.asarray(o.center_ned_m) for o in obstacles],
                half_sizes=[[o.radius_m] * 3 for o in obstacles],
                colors=[_ORANGE],
            ),
        )
        self._log_tracks(out.guidance, pos, vel)
        aim = out.guidance.aiming_point_ned_m
        rec.log(
            "world/aiming_point",
            rr.Points3D([] if aim is None else [aim], colors=[_RED], radii=[0.12]),
        )
        rec.log(
            "world/setpoint",
            rr.Points3D([out.setpoint_ned_m], colors=[(255, 0, 255)], radii=[0.15]),
        )
        if goal_ned_m is not None:
            rec.log("world/goal", rr.Points3D([goal_ned_m], colors=[_GREEN], radii=[0.25]))
        if heavy and known_space is not None:
            occ = known_space.occupied_points_ned_m()
            rec.log("world/known_space", rr.Points3D(occ, colors=[(*_GREY, 90)], radii=[0.08]))
        self._log_status(out)

    def _log_vehicle(self, pos: np.ndarray, vel: np.ndarray, R: np.ndarray) -> None:
        """The vehicle's pose, its trail (every ``trail_every`` steps) and its velocity."""
        rr, rec = self.rr, self.rec
        rec.log("world/vehicle", rr.Transform3D(translation=pos, mat3x3=R))
        self._trail.append(pos.tolist())
        self._steps += 1
        if len(self._trail) >= 2 and self._steps % self.trail_every == 0:
            rec.log(
                "world/trail", rr.LineStrips3D([list(self._trail)], colors=[_BLUE], radii=[0.03])
            )
        rec.log("world/velocity", rr.Arrows3D(origins=[pos], vectors=[vel], colors=[_BLUE]))

    def _log_images(self, frame: StereoFrame, depth, pos: np.ndarray, R: np.ndarray) -> None:
        """The left image, the depth map, its near/unknown classes and the near points."""
        rr, rec = self.rr, self.rec
        if frame.left is not None:  # a depth camera's frame may come without its picture
            rec.log(f"{_CAM}/image", rr.Image(frame.left))
        if depth is None:
            return
        with np.errstate(invalid="ignore"):
            mm = np.where(np.isfinite(depth), np.clip(depth * 1000.0, 0, 65535), 0.0)
        rec.log(f"{_CAM}/depth", rr.DepthImage(mm.astype(np.uint16), meter=1000.0))
        classes = depth_classes(depth, self.threshold_m)
        rec.log(f"{_CAM}/classes", rr.SegmentationImage(classes, opacity=0.5))
        pts = near_points_ned_m(depth, self.threshold_m, frame.intrinsics, pos, R)
        rec.log("world/obstacle_points", rr.Points3D(pts, colors=[_ORANGE], radii=[0.03]))

    def _log_tracks(self, g, pos: np.ndarray, vel: np.ndarray) -> None:
        """Guidance's confirmed tracks (the active one red) and their collision cones (red
        where the velocity lies inside)."""
        rr, rec = self.rr, self.rec
        active = g.active_obstacle.track_id if g.active_obstacle is not None else None
        centers, sizes, colors, cones, cone_colors = [], [], [], [], []
        for t in g.tracks:
            c, r = np.asarray(t.sphere.center_ned_m, dtype=float), float(t.sphere.radius_m)
            centers.append(c)
            sizes.append([r, r, r])
            colors.append(_RED if t.track_id == active else _GREEN)
            lines = cone_lines_ned_m(pos, c, r)
            critical = velocity_in_cone(pos, vel, c, r)
            cones.extend(lines)
            cone_colors.extend([_RED if critical else _GREEN] * len(lines))
        rec.log("world/tracks", rr.Ellipsoids3D(centers=centers, half_sizes=sizes, colors=colors))
        rec.log("world/cones", rr.LineStrips3D(cones, colors=cone_colors, radii=[0.01]))

    def _log_status(self, out) -> None:
        """The avoidance flag, speed and its limit, the free distance, the mode."""
        rr, rec = self.rr, self.rec
        g, env = out.guidance, out.envelope
        rec.log("status/avoidance_flag", rr.Scalars([1.0 if g.avoidance_flag else 0.0]))
        rec.log("status/speed_mps", rr.Scalars([float(env.speed_mps)]))
        rec.log("status/speed_limit_mps", rr.Scalars([float(env.speed_limit_mps)]))
        free = float(env.free_distance_m)
        if np.isfinite(free):
            rec.log("status/free_distance_m", rr.Scalars([free]))
        rec.log("status/mode", rr.TextLog(f"{g.mode.value} ({g.reason.value})", level="INFO"))


class RerunObserver(CompanionObserver):
    """The companion's Rerun view (``companion --rerun``); logs on a thread of its own.

    It draws the core's :class:`~companion.core.events.FrameProcessed` outputs (the core
    reports them because ``wants_pipeline`` is set).

    Parameters
    ----------
    target : RerunTarget
    max_pending : frames queued beyond which new ones are skipped (the view lags, the
        companion does not).
    known_space_every : draw the known-space voxels every this many logged frames.
    rate_hz : frames are logged at most this often (capture time; the others are counted
        as decimated): a live view for a person, not a flight record (``--record`` keeps
        every frame, and ``stereo-avoid replay FILE.mcap --rerun`` logs them all).
    """

    wants_pipeline = True  # the core reports FrameProcessed

    def __init__(
        self,
        target: RerunTarget,
        *,
        max_pending: int = 8,
        known_space_every: int = 5,
        rate_hz: float = 10.0,
    ) -> None:
        self.target = target
        self._period_ns = round(1e9 / rate_hz)
        self._last_ns: int | None = None
        self.decimated = 0
        self.max_pending = max_pending
        self.known_space_every = known_space_every
        self.skipped = 0
        self.logged = 0
        self._queue: queue.Queue = queue.Queue(maxsize=max_pending)
        self._thread: threading.Thread | None = None
        self._rec = None
        self._logger: RerunLogger | None = None

    def on_start(self, config, instance_id: int) -> None:
        self._rec = open_stream(self.target, f"companion_{config.vehicle_id}")
        self._logger = RerunLogger(self._rec, config.perception.threshold_m)
        self._thread = threading.Thread(target=self._run, name="rerun-logger", daemon=True)
        self._thread.start()
        _log.info("Rerun view: %s", self.target.describe())

    def on_step(self, event, outputs) -> None:
        if self._logger is None:
            return
        for out in outputs:
            if isinstance(out, FrameProcessed):
                self._offer(out)

    def _offer(self, done: FrameProcessed) -> None:
        t = done.frame.capture_ns
        if self._last_ns is not None and 0 <= t - self._last_ns < self._period_ns:
            self.decimated += 1
            return
        self._last_ns = t
        try:  # the goal array is replaced, never modified; the grid is read on the thread
            self._queue.put_nowait(
                (done.frame, done.pose, done.step.output, done.goal_ned_m, done.known_space)
            )
        except queue.Full:
            self.skipped += 1

    def close(self) -> None:
        if self._thread is None:
            return
        self._queue.put(None)
        self._thread.join(timeout=30.0)
        self._thread = None
        if self._rec is not None:
            self._rec.flush()
            if self.target.path is not None:
                self._rec.disconnect()
        _log.info(
            "Rerun view closed: %d frames logged, %d skipped, %d decimated",
            self.logged,
            self.skipped,
            self.decimated,
        )

    def _run(self) -> None:
        assert self._logger is not None
        n = 0
        while True:
            item = self._queue.get()
            if item is None:
                break
            frame, pose, output, goal, known = item
            n += 1
            try:
                self._logger.log_step(
                    frame,
                    pose,
                    output,
                    goal_ned_m=goal,
                    known_space=known if n % self.known_space_every == 1 else None,
                )
                self.logged += 1
            except Exception as exc:  # the view must never take the companion down
                _log.error("Rerun logging failed (%s: %s); view stopped", type(exc).__name__, exc)
                break
