"""Obstacle memory: boundary spheres that outlive the camera's field of view.

The paper (§6.2) returns to the goal as soon as the obstacle leaves the field of view. A
forward camera loses a sphere while the vehicle is still beside it, so we remember each
boundary sphere (NED, with the simulation time it was last seen) while it still matters.

Rules (parameters in :class:`~companion.guidance.config.GuidanceConfig`):

* **Merge.** Each detection updates the nearest remembered obstacle it overlaps: centres
  within ``merge_distance_m``, or either centre inside the other sphere; otherwise it
  starts a new one with a fresh id. Several detections may update one obstacle in one
  frame (a close obstacle seen in fragments). The merged sphere is the smallest sphere
  enclosing both: a remembered obstacle never shrinks. Close up, the camera sees only a
  cap of a large obstacle, or loses part of it at the image border; a blend would let
  such partial views shrink the boundary exactly when the vehicle is beside it.
* **Forget.** An obstacle not seen in this update is dropped when it has been unseen for
  more than ``memory_timeout_s``, or when it is *passed*: its centre is behind the vehicle
  (``(c - p)·v < 0`` with speed ≥ ``min_speed_mps``), its surface is farther than
  ``forget_distance_m``, and it does not block the straight segment to the goal. An
  obstacle seen in this update is always kept.
* **Capacity.** At most ``max_tracks`` are kept, the most recently seen first (ties: the
  older id).
* **Confirmation.** A track is *confirmed* once it was detected in ``confirm_n`` of the
  last ``confirm_m`` updates, or at once when its surface is nearer than
  ``confirm_immediate_m`` (inside the stopping distance there is no time to wait); an
  unconfirmed track not detected for ``confirm_m`` updates is dropped. Guidance avoids
  confirmed tracks only, so one false detection is not a 10 s stop; the known-space map
  (the safety envelope) still stops the vehicle short of anything seen, confirmed or not.
* **Timeout.** ``memory_timeout_s`` forgets only a track whose surface is farther than
  ``forget_distance_m``: an obstacle beside or above the vehicle is never timed out.

Map pieces (keyed detections)
-----------------------------
A detection with an integer ``track_key`` (a piece of the known-space map,
:mod:`companion.guidance.map_boundaries`) is not merged: the map already *is* the memory
(occupied space persists until seen free, and is confirmed over two frames before it is
occupied). The track with that id takes the detection's sphere as it is — it may shrink
when space is seen free, and it never grows by merging — and is confirmed at once; a
keyed track missing from an update is gone from the map's reach and is dropped. Keyed
tracks do not count against ``max_tracks`` (dropping a piece of a wall would open a false
gap). The rules above apply to detections without a key (perception's per-frame spheres).

Pure functions over frozen values; time is simulation time passed in by the caller.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, replace

import numpy as np

from companion.guidance._vec import norm3
from companion.guidance.cone import BoundarySphere, SphereLike, segment_intersects_sphere
from companion.guidance.config import GuidanceConfig

__all__ = ["ObstacleMemory", "TrackedObstacle", "update_memory"]


@dataclass(frozen=True)
class TrackedObstacle:
    """A remembered boundary sphere.

    Attributes
    ----------
    track_id : int
        Stable id, unique within one memory.
    sphere : BoundarySphere
        Current estimate (NED [m]).
    first_seen_s, last_seen_s : float
        Simulation times of the first and the latest detection [s].
    n_detections : int
        Detections merged into it so far.
    recent : int
        Bit mask of the latest updates that detected it (bit 0: the latest).
    confirmed : bool
        See "Confirmation" in the module docstring.
    keyed : bool
        A map piece (see "Map pieces" in the module docstring); ``track_id`` is its key.
    """

    track_id: int
    sphere: BoundarySphere
    first_seen_s: float
    last_seen_s: float
    n_detections: int = 1
    recent: int = 1
    confirmed: bool = True
    keyed: bool = False


@dataclass(frozen=True)
class ObstacleMemory:
    """The remembered obstacles, ordered by id, and the next id to hand out.

    Attributes
    ----------
    tracks : tuple of TrackedObstacle
    next_id : int
    """

    tracks: tuple[TrackedObstacle, ...] = ()
    next_id: int = 0

    def get(self, track_id: int | None) -> TrackedObstacle | None:
        """The track with ``track_id``, or None."""
        for track in self.tracks:
            if track.track_id == track_id:
                return track
        return None


def _merge(old: BoundarySphere, new: BoundarySphere) -> BoundarySphere:
    """Smallest sphere enclosing ``old`` and ``new``."""
    c_old = np.asarray(old.center_ned_m)
    c_new = np.asarray(new.center_ned_m)
    gap = norm3(c_new - c_old)
    if gap + new.radius_m <= old.radius_m:
        return old
    if gap + old.radius_m <= new.radius_m:
        return new
    radius = 0.5 * (gap + old.radius_m + new.radius_m)
    center = c_old + (radius - old.radius_m) / gap * (c_new - c_old)
    return BoundarySphere(center_ned_m=tuple(center), radius_m=radius)


def _overlaps(det: BoundarySphere, trk: BoundarySphere, gap_m: float, config) -> bool:
    return gap_m <= config.merge_distance_m or gap_m < max(det.radius_m, trk.radius_m)


def _is_passed(
    sphere: BoundarySphere,
    pos: np.ndarray,
    vel: np.ndarray,
    goal: np.ndarray | None,
    config: GuidanceConfig,
) -> bool:
    speed = norm3(vel)
    if speed < max(config.min_speed_mps, 1e-9):
        return False
    offset = np.asarray(sphere.center_ned_m) - pos
    if float(offset @ vel) >= 0.0:
        return False
    if norm3(offset) - sphere.radius_m <= config.forget_distance_m:
        return False
    return goal is None or not segment_intersects_sphere(pos, goal, sphere)


def update_memory(
    memory: ObstacleMemory,
    detections: Iterable[SphereLike],
    *,
    time_s: float,
    pos_ned_m,
    vel_ned_mps,
    goal_ned_m=None,
    config: GuidanceConfig,
) -> ObstacleMemory:
    """Merge this frame's boundary spheres into the memory and forget what no longer matters.

    Parameters
    ----------
    memory : ObstacleMemory
        Memory after the previous update.
    detections : iterable of SphereLike
        Boundary spheres perceived in this frame (centre NED [m], inflated radius [m]).
    time_s : float
        Simulation time of the frame [s].
    pos_ned_m, vel_ned_mps : array_like, shape (3,)
        Vehicle position [m] and velocity [m/s], NED.
    goal_ned_m : array_like, shape (3,), optional
        Goal [m, NED]; an obstacle blocking the straight path to it is not "passed".
    config : GuidanceConfig

    Returns
    -------
    ObstacleMemory
        New memory (the input is not modified); tracks ordered by id.
    """
    pos = np.asarray(pos_ned_m, dtype=float)
    vel = np.asarray(vel_ned_mps, dtype=float)
    goal = None if goal_ned_m is None else np.asarray(goal_ned_m, dtype=float)
    keys_detections = [(_key(d), d) for d in detections]
    keyed = _keyed_tracks(memory, [kd for kd in keys_detections if kd[0] is not None], time_s)
    spheres = [BoundarySphere.of(d) for key, d in keys_detections if key is None]

    tracks = [t for t in memory.tracks if not t.keyed]
    n_remembered = len(tracks)
    next_id, seen = _associate(tracks, spheres, memory.next_id, time_s, config)
    _confirm(tracks, seen, n_remembered, pos, config)

    def far(trk: TrackedObstacle) -> bool:
        centre = np.asarray(trk.sphere.center_ned_m)
        return norm3(centre - pos) - trk.sphere.radius_m > config.forget_distance_m

    kept = [
        trk
        for i, trk in enumerate(tracks)
        if i in seen
        or not (
            (time_s - trk.last_seen_s > config.memory_timeout_s and far(trk))
            or _is_passed(trk.sphere, pos, vel, goal, config)
            or (not trk.confirmed and trk.recent == 0)
        )
    ]
    if len(kept) > config.max_tracks:
        kept.sort(key=lambda t: (-t.last_seen_s, t.track_id))
        kept = kept[: config.max_tracks]
    kept.sort(key=lambda t: t.track_id)
    return ObstacleMemory(tracks=tuple(kept) + keyed, next_id=next_id)


def _associate(
    tracks: list[TrackedObstacle], spheres, next_id: int, time_s: float, config: GuidanceConfig
) -> tuple[int, set[int]]:
    """Merge ``spheres`` into ``tracks`` (in place): each updates the nearest overlapping
    remembered obstacle (by centre gap), so association does not depend on the detection
    order; the others become new tracks. Returns the next free id and the indices of the
    tracks updated or added."""
    seen: set[int] = set()
    matched_det: set[int] = set()
    n_remembered = len(tracks)
    for i_det, det in enumerate(spheres):
        c_det = np.asarray(det.center_ned_m)
        best: tuple[float, int] | None = None
        for i_trk in range(n_remembered):
            trk_sphere = tracks[i_trk].sphere
            gap = norm3(c_det - np.asarray(trk_sphere.center_ned_m))
            if _overlaps(det, trk_sphere, gap, config) and (best is None or gap < best[0]):
                best = (gap, i_trk)
        if best is None:
            continue
        matched_det.add(i_det)
        i_trk = best[1]
        trk = tracks[i_trk]
        tracks[i_trk] = replace(
            trk,
            sphere=_merge(trk.sphere, det),
            last_seen_s=time_s,
            n_detections=trk.n_detections + (0 if i_trk in seen else 1),
        )
        seen.add(i_trk)
    for i_det, det in enumerate(spheres):
        if i_det in matched_det:
            continue
        seen.add(len(tracks))
        tracks.append(
            TrackedObstacle(
                track_id=next_id,
                sphere=det,
                first_seen_s=time_s,
                last_seen_s=time_s,
                confirmed=False,
            )
        )
        next_id += 1
    return next_id, seen


def _confirm(
    tracks: list[TrackedObstacle], seen: set[int], n_remembered: int, pos, config: GuidanceConfig
) -> None:
    """N-of-M confirmation (in place): the detection history shifts, a track seen in
    ``confirm_n`` of the last ``confirm_m`` updates, or within ``confirm_immediate_m`` of the
    vehicle, is confirmed for good."""
    mask = (1 << config.confirm_m) - 1
    for i, trk in enumerate(tracks):
        recent = ((trk.recent << 1) | (1 if i in seen else 0)) & mask
        if i >= n_remembered:
            recent = 1  # new this update
        surface = norm3(np.asarray(trk.sphere.center_ned_m) - pos) - trk.sphere.radius_m
        confirmed = trk.confirmed or (
            i in seen
            and (recent.bit_count() >= config.confirm_n or surface < config.confirm_immediate_m)
        )
        tracks[i] = replace(trk, recent=recent, confirmed=confirmed)


def _key(detection) -> int | None:
    key = getattr(detection, "track_key", None)
    if key is None:
        return None
    if isinstance(key, bool) or not isinstance(key, int | np.integer):
        raise ValueError(f"track_key must be an integer, got {key!r}")
    return int(key)


def _keyed_tracks(
    memory: ObstacleMemory, keyed_detections: list[tuple[int, SphereLike]], time_s: float
) -> tuple[TrackedObstacle, ...]:
    """This update's map pieces, ``(track_key, detection)``, as tracks (see "Map
    pieces"), ordered by key."""
    previous = {t.track_id: t for t in memory.tracks if t.keyed}
    by_key: dict[int, TrackedObstacle] = {}
    for key, det in keyed_detections:
        if key in by_key:
            raise ValueError(f"two detections share track_key {key}")
        old = previous.get(key)
        by_key[key] = TrackedObstacle(
            track_id=key,
            sphere=BoundarySphere.of(det),
            first_seen_s=time_s if old is None else old.first_seen_s,
            last_seen_s=time_s,
            n_detections=1 if old is None else old.n_detections + 1,
            keyed=True,
        )
    return tuple(by_key[k] for k in sorted(by_key))
