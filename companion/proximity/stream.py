"""OBSTACLE_DISTANCE watchdog thread: the proximity stream does not wait for a frame.

The autopilot drops the companion's proximity data 0.5 s after the last message
(:mod:`companion.proximity.sender`), and a pilot then flies on without avoidance. Sent
from the companion's one loop, the stream stopped while a frame was processed: on a loaded
2-core machine the loop once sent nothing for 0.87 s (issue 34), and the held stick flew
the vehicle into the wall. The main loop still sends (each frame's sectors, and between
frames), and the service (:mod:`companion.service`) runs :class:`ProximityStream`, a
thread that looks every half period and, when nothing went out for :data:`GAP_PERIODS`
periods (75 ms at 20 Hz), sends itself:

1. reads the MAVLink link itself (under the link's lock) and hands what it read to the
   main loop (:meth:`ProximityStream.take_inbox`, a wake-up pipe for its ``select``): the
   vehicle's position keeps arriving while the main loop is busy with a frame;
2. places the vehicle from the newest LOCAL_POSITION_NED (carried forward by its velocity,
   :func:`~companion.proximity.sender.position_at_send`) and ATTITUDE of the autopilot;
3. computes the sectors from a :class:`MapSnapshot`, a copy of the known-space map's
   slab around the vehicle's height band that the main loop takes after each frame
   (:func:`snapshot_map`, ~0.1 ms), never the live map a frame is updating;
4. sends OBSTACLE_DISTANCE (under the link's lock), stamped with the snapshot's capture
   time.

The sector kernel (:func:`~companion.proximity.sectors.sectors_from_map`) is compiled
with ``nogil``, and the matcher (OpenCV) releases the GIL. In normal running the thread
only reads a time (microseconds of the interpreter), so the main loop's work is as
before; a thread that sent every period competed for the GIL on a loaded machine and slowed
the frames it was meant not to wait for. Its sends are counted in the core's sender
(count, rate, late sends, stale poses) and as ``fills`` here.

A snapshot's slab is the height band widened by :data:`SLAB_MARGIN_M` each way: a vehicle
that has climbed or sunk beyond it before the next frame sees its band as outside the
grid, unknown — never clear.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from companion.known_space import KnownSpace, KnownSpaceConfig
from companion.link.messages import obstacle_distance_message
from companion.proximity.sectors import ProximityConfig, sectors_from_map
from companion.proximity.sender import ProximitySender, position_at_send

__all__ = [
    "GAP_PERIODS",
    "SLAB_MARGIN_M",
    "MapSnapshot",
    "ProximityStream",
    "TelemetryPose",
    "VehiclePose",
    "snapshot_map",
    "warm_up",
]

#: The watchdog sends when nothing went out for this many periods.
GAP_PERIODS = 1.5
#: The snapshot keeps this much of the map [m] above and below the height band and its
#: unseen extension: 2.5 m/s of climb (ArduCopter's PILOT_SPEED_UP) for 0.8 s.
SLAB_MARGIN_M = 2.0
_WARM_CONFIG = ProximityConfig()  # the warm-up's (the kernel's types do not depend on it)
_LATE_S = 0.25  # a send this long after the previous one is logged [s host]
_log = logging.getLogger("companion")
_MAX_POS_M = 1e5  # as the core's telemetry checks (companion.core.telemetry_job)
_MAX_SPEED_MPS = 300.0


@dataclass(frozen=True, eq=False)
class MapSnapshot:
    """One layer of the known-space map, copied: what
    :func:`~companion.proximity.sectors.sectors_from_map` reads of a :class:`KnownSpace`."""

    grid: np.ndarray  # (nx, ny, nz) int8 voxel states, a slab of the layer
    origin_vox: np.ndarray  # global voxel index of grid[0, 0, 0]
    config: KnownSpaceConfig
    range_m: float
    frames: int
    far: MapSnapshot | None
    capture_ns: int | None  # the newest frame in the map (frame clock)


@dataclass(frozen=True)
class VehiclePose:
    """The autopilot's newest position (with its velocity and host receipt time) and yaw."""

    pos_ned_m: tuple[float, float, float]
    vel_ned_mps: tuple[float, float, float]
    received_ns: int  # host monotonic clock
    yaw_rad: float | None


class TelemetryPose:
    """The autopilot's newest LOCAL_POSITION_NED (range-checked, with its host receipt time)
    and ATTITUDE yaw, as read by whichever thread or process reads the link.

    Parameters
    ----------
    autopilot : (int, int)
        System and component id of the autopilot whose telemetry places the vehicle.
    """

    def __init__(self, autopilot: tuple[int, int]) -> None:
        self._autopilot = autopilot
        self._lock = threading.Lock()
        self._pos: tuple | None = None  # (pos, vel, received_ns)
        self._yaw: float | None = None

    def observe(self, msg, now_ns: int) -> bool:
        """Keep ``msg`` if it places the vehicle; True for a position taken."""
        if (msg.get_srcSystem(), msg.get_srcComponent()) != self._autopilot:
            return False
        mtype = msg.get_type()
        if mtype == "LOCAL_POSITION_NED":
            pos, vel = (msg.x, msg.y, msg.z), (msg.vx, msg.vy, msg.vz)
            if _in_range(pos, _MAX_POS_M) and _in_range(vel, _MAX_SPEED_MPS):
                with self._lock:
                    self._pos = (pos, vel, now_ns)
                return True
        elif mtype == "ATTITUDE" and _in_range((msg.yaw,), 2.0 * math.pi):
            with self._lock:
                self._yaw = float(msg.yaw)
        return False

    def pose(self) -> VehiclePose | None:
        """The newest pose (None before a position)."""
        with self._lock:
            if self._pos is None:
                return None
            pos, vel, received_ns = self._pos
            return VehiclePose(pos, vel, received_ns, self._yaw)


def warm_up() -> None:
    """Compile (or load from numba's cache) the sector kernels: sectors of a tiny map."""
    tiny = KnownSpace(KnownSpaceConfig(size_xy_vox=8, size_z_vox=8, far_range_m=0.0))
    tiny.frames = 1
    sectors_from_map(snapshot_map(tiny, -0.8, 0.4, None), (0.0, 0.0, 0.0), 0.0, _WARM_CONFIG)


def snapshot_map(
    space: KnownSpace, down_m: float | None, half_height_m: float, capture_ns: int | None
) -> MapSnapshot:
    """A copy of ``space`` (and its far layer) from ``half_height_m`` [m] above and below
    ``down_m`` [m, NED] (None: all of it), for a thread to read while the map moves on."""
    grid, origin_vox = _slab(space, down_m, half_height_m)
    return MapSnapshot(
        grid=grid,
        origin_vox=origin_vox,
        config=space.config,
        range_m=float(space.range_m),
        frames=int(space.frames),
        far=None
        if space.far is None
        else snapshot_map(space.far, down_m, half_height_m, capture_ns),
        capture_ns=capture_ns,
    )


def _slab(space: KnownSpace, down_m: float | None, half_height_m: float):
    origin = np.array(space.origin_vox, dtype=np.int64)
    if down_m is None or not math.isfinite(down_m):
        return space.grid.copy(), origin
    inv = 1.0 / space.config.voxel_m
    nz = space.grid.shape[2]
    k0 = max(0, math.floor((down_m - half_height_m) * inv) - int(origin[2]))
    k1 = min(nz, math.floor((down_m + half_height_m) * inv) - int(origin[2]) + 1)
    if k1 <= k0:  # the band lies outside the layer: nothing of it is known
        k0, k1 = 0, 0
    origin[2] += k0
    return space.grid[:, :, k0:k1].copy(), origin


class ProximityStream:
    """The thread that keeps OBSTACLE_DISTANCE on the wire (module docstring).

    Parameters
    ----------
    sender : ProximitySender
        The core's sender: configuration, schedule and figures (thread-safe).
    poll : callable
        Reads every MAVLink message waiting (the service holds the link's lock).
    send : callable
        Sends one MAVLink message (the service holds the link's lock).
    autopilot : (int, int)
        System and component id of the autopilot whose telemetry places the vehicle.
    """

    def __init__(
        self,
        sender: ProximitySender,
        poll: Callable[[], list],
        send: Callable[[object], object],
        autopilot: tuple[int, int],
    ) -> None:
        self.sender = sender
        self._poll = poll
        self._send = send
        self._telemetry = TelemetryPose(autopilot)
        self._lock = threading.Lock()
        self._inbox: deque = deque()
        self._map: MapSnapshot | None = None
        self._clock_rate = 1.0  # frame-clock seconds per host second (core's estimate)
        self._stamp_ns = 0  # newest frame-clock stamp, before any frame
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._rfd, self._wfd = os.pipe()
        os.set_blocking(self._rfd, False)
        os.set_blocking(self._wfd, False)
        self.fills = 0  # sends of the thread's own (the main loop was late)
        self.errors = 0

    # ---- main loop side ----------------------------------------------------------------
    def start(self) -> None:
        """Compile (or load from numba's cache) the sector kernel here, not on the thread
        in flight, then start sending."""
        warm_up()
        self._thread = threading.Thread(target=self._run, name="obstacle-distance", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        for fd in (self._rfd, self._wfd):
            with contextlib.suppress(OSError):
                os.close(fd)

    def fileno(self) -> int:
        """Readable when the thread has read MAVLink messages for the main loop."""
        return self._rfd

    def take_inbox(self) -> list:
        """The messages the thread read, oldest first (the main loop steps its core with
        them before reading the link itself)."""
        with contextlib.suppress(OSError):
            while os.read(self._rfd, 4096):
                pass
        out = []
        while self._inbox:
            out.append(self._inbox.popleft())
        return out

    def observe(self, messages, now_ns: int) -> None:
        """Telemetry the main loop read (the vehicle's pose for the next send)."""
        for msg in messages:
            self._observe(msg, now_ns)

    def set_map(self, snapshot: MapSnapshot | None) -> None:
        """The map as of the newest processed frame (None: no map, e.g. after a reset)."""
        with self._lock:
            self._map = snapshot

    def set_clock(self, rate: float, stamp_ns: int | None) -> None:
        """The core's frame-clock rate and newest frame-clock stamp (after each step)."""
        with self._lock:
            self._clock_rate = rate if math.isfinite(rate) and rate > 0.0 else 1.0
            if stamp_ns is not None:
                self._stamp_ns = max(int(stamp_ns), 0)

    def figures(self) -> dict:
        """The thread's own sends (the main loop was late), its errors, and the longest
        time between any two sends [s host]."""
        return {
            "fills": self.fills,
            "errors": self.errors,
            "longest_gap_s": round(self.sender.longest_gap_s, 3),
        }

    # ---- the thread --------------------------------------------------------------------
    def _run(self) -> None:
        period_s = self.sender.period_s
        gap_s = GAP_PERIODS * period_s
        while not self._stop.wait(0.5 * period_s):
            now_s = time.monotonic()
            since_s = self.sender.since_send_s(now_s)
            if since_s < gap_s:
                continue  # the main loop keeps the rate
            if math.isfinite(since_s) and since_s > _LATE_S:
                _log.warning(
                    "OBSTACLE_DISTANCE late: %.3f s since the previous send (the autopilots "
                    "drop the data after 0.5 s)",
                    since_s,
                )
            try:
                self._read_link()
                self._send_now(now_s)
                self.fills += 1
            except Exception:  # a bug here must not end the stream: counted
                self.errors += 1

    def _read_link(self) -> None:
        messages = self._poll()
        if not messages:
            return
        now_ns = time.monotonic_ns()
        for msg in messages:
            self._observe(msg, now_ns)
        self._inbox.extend(messages)
        with contextlib.suppress(BlockingIOError):
            os.write(self._wfd, b"m")

    def _observe(self, msg, now_ns: int) -> None:
        self._telemetry.observe(msg, now_ns)

    def pose(self) -> VehiclePose | None:
        """The newest pose the stream knows (None before a position)."""
        return self._telemetry.pose()

    def _send_now(self, now_s: float) -> None:
        with self._lock:
            snapshot, rate, stamp_ns = self._map, self._clock_rate, self._stamp_ns
        pose = self.pose()
        pos = yaw = None
        if pose is not None and pose.yaw_rad is not None:
            age_s = (time.monotonic_ns() - pose.received_ns) * 1e-9 * rate
            pos = position_at_send(pose.pos_ned_m, pose.vel_ned_mps, age_s)
            if pos is None:
                self.sender.count_stale_pose()
            else:
                yaw = pose.yaw_rad
        if snapshot is not None and snapshot.capture_ns is not None:
            stamp_ns = snapshot.capture_ns
        sectors = self.sender.on_timer(snapshot, pos, yaw, now_s)
        self._send(obstacle_distance_message(stamp_ns // 1000, sectors))


def _in_range(values, bound: float) -> bool:
    return all(math.isfinite(v) and abs(v) <= bound for v in values)
