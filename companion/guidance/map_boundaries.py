"""Collision safety boundaries (paper Fig. 4) built from the known-space map.

The paper forms one sphere per detected obstacle. Fitted to what one frame shows, that
sphere must grow to cover an extended obstacle (a 9.6 × 6 m wall became a 12.4 m sphere:
a goal beyond the wall looked "inside", an 8 m climb over a 1.2 m wall). Here the
boundaries come from the known-space map (:mod:`companion.known_space`) instead: its
OCCUPIED voxels, which persist until seen free, are cut into pieces of bounded size
(:meth:`~companion.known_space.KnownSpace.pieces`, cubes of 1.2 m), and each piece gets
its own sphere, so the cone and aiming-point logic of §5 runs unchanged on several
spheres per extended obstacle.

One piece's sphere
------------------
* **Cells.** The sphere about the piece's centroid ``c`` enclosing its voxels, radius
  ``r`` (at most ``piece_vox · voxel · √3 / 2``, 1.04 m by default).
* **Blind spot** (Fig. 4: the far side of an obstacle, which the camera cannot see, is
  obstacle too). Along the bearing ``u`` from the vehicle to ``c`` the space behind the
  piece is unseen for ``e = min(blind_depth_m, distance from c to the first FREE voxel
  along u)``; the sphere encloses the piece and its copy moved back by ``e``: centre
  ``c + u e / 2``, radius ``r + e / 2``. Space seen free behind the piece (from another
  viewpoint) ends the blind spot early.
* **Inflation.** ``+ inflate_m`` (vehicle radius + safety margin, as perception's spheres).

Only pieces with an OCCUPIED voxel within ``detect_range_m`` of the vehicle are
boundaries (the paper's detection threshold, 4 m in §6: avoidance starts where the paper
starts it). Occupied space beyond it still stops the vehicle through the safety envelope.

The goal and the real surface
-----------------------------
An inflated sphere can hold a goal that is in fact clear of the obstacle (a goal 1 m in
front of a wall). The goal's clearance is therefore measured from the real surface, the
OCCUPIED voxels: the goal is *blocked* by a piece when it lies within ``inflate_m`` of the
piece's nearest voxel surface, or, when its own voxel is not FREE and the piece hides it
from the vehicle (:func:`in_shadow`: the line of sight passes the piece before the goal),
within ``inflate_m + blind_depth_m`` (it may lie in the blind spot, inside the obstacle).
An unseen goal beside or in front of a seen surface is not in its blind spot. A piece whose sphere
holds a goal that is not blocked is replaced by its eight sub-pieces (cubes of half the
edge, at most 0.52 m radius); a sub-piece sphere holding the goal is trimmed to end just
short of it (its blind spot dropped and its inflation reduced: the goal's clearance from
the real surface is at least ``inflate_m``, and the safety envelope still keeps every
setpoint in space seen free). A sub-piece too wide to trim (the goal nearer
its centroid than its voxels reach) keeps its full sphere: the goal counts as blocked, and
guidance stops short of it, reported. Guidance then sees a goal inside a sphere exactly
when it is blocked (``Reason.GOAL_UNREACHABLE``).

Gaps stay open
--------------
The enclosing sphere of a piece and its blind spot grows sideways by ``e / 2`` and by the
piece's own extent: two pieces at the edges of a 3 m opening in a wall (or the two walls
of a corridor) each reach ~1.5 m into it and the opening closes although the vehicle and
its margins fit (issue 36: the vehicle detoured round a 30 m wall, or never entered a
corridor). So every pair of boundary spheres that overlap while the real surfaces behind
them leave a passable gap, ``|c_a − c_b| − r_a − r_b ≥ 2 · inflate_m`` (piece centroids
``c``, piece radii ``r``: a lower bound on the voxels' distance) with no third piece
between them (no piece's ``r + inflate_m`` reaching the part of the segment ``c_a c_b``
between the two inflated pieces: the rest of the same wall), are *opened*: each becomes
the piece's own inflated sphere ``(c, r + inflate_m)``, without the blind spot's growth.
The inflated pieces are then at least ``|c_a − c_b| − r_a − r_b − 2 · inflate_m ≥ 0``
apart: the opening the vehicle fits through stays open to the cone and the aiming point
(§5 unchanged). Only pairs are opened: a single sphere across the straight path by its
growth alone is kept whole (opening it let a goal-near Monte Carlo seed, 762, pass 0.247 m
from a sphere whose unseen back the growth had covered), so an opening whose far side is
not yet within the detection range still looks closed until it is. An opened
piece's blind spot is no longer in its cone sphere, but it stays unknown space (the safety
envelope never puts a carrot there) and the solid extent (:func:`solid_extent`) stays the
whole sphere of piece and blind spot, so the envelope's near-field excuse never applies
there.
Pairs are tested in numpy, one vectorised pass (no per-pair Python loop): the corridor's
two long walls give a few hundred pairs.

Openings seen free
------------------
The pair rule above bounds a piece by its sphere, and a wall's piece at the edge of an
opening is a flat cube whose sphere is set by its height: with stereo's edges (a 2.7 m
opening maps 2.0–2.2 m wide between its occupied voxels) no pair passed it, and the
spheres of the edge pieces and their neighbours, grown by the blind spot, closed the
opening the map had seen free (passage Monte Carlo seeds 0 and 112: the vehicle paced
along the wall for a minute, no path through it either, since the path search avoids
the spheres). So every boundary that holds a point of an opening seen free (the middle
between two pieces whose voxels leave the vehicle and its margins room, FREE and clear of
every surface, and the voxel centres about it a path would cross) is made smaller, one
step at a time while it still holds one: its own sphere without the blind spot's growth,
then its sub-pieces, then a sub-piece's voxels nearest the opening one by one and the
rest as one sphere (:mod:`companion.guidance.openings`, with the bound: open to the cone
rule from 1.6 m between the voxels' faces, to the path search from 1.8 m, on the 0.2 m
grid; closed below 2 · ``inflate_m``). Every sphere still encloses its voxels and the
inflation; the blind spot dropped stays in the solid extent and is unknown space.
Sub-piece, voxel and rest spheres have their own track keys (levels 1, 2 and 3).

Each boundary carries a stable ``track_key``: the global index of its cube (and its
level), the same in every frame, so guidance's hysteresis and side commitment follow a
piece from frame to frame; the obstacle memory replaces a keyed track's sphere each frame
instead of growing it (:mod:`companion.guidance.memory`).

Pure: the map is read, never written; no clock, no I/O.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from companion.guidance.openings import covers, opening_points, split_for_openings
from companion.known_space import FREE, KnownSpace, Pieces
from protocols.config import Checked, bounded

__all__ = [
    "MapBoundary",
    "MapBoundaryConfig",
    "goal_surely_blocked",
    "in_shadow",
    "map_boundaries",
    "solid_extent",
    "track_key",
]

_KEY_FLAG = 1 << 62  # keyed tracks: ids far above the memory's own counter
_KEY_OFFSET = 1 << 19  # cube indices within ±2^19 (±629 km at 1.2 m cubes)
_TRIM_EPS_M = 1e-3  # a trimmed sphere ends this far short of the goal


def track_key(level: int, cube: np.ndarray) -> int:
    """Stable track id of the cube ``cube`` (3 ints) at ``level`` (0 piece, 1 sub-piece,
    2 voxel, 3 the rest of a sub-piece kept open: module docstring)."""
    i, j, k = (int(v) + _KEY_OFFSET for v in cube)
    if not (0 <= i < 1 << 20 and 0 <= j < 1 << 20 and 0 <= k < 1 << 20):
        raise ValueError(f"cube index {tuple(int(v) for v in cube)} out of the key range")
    return _KEY_FLAG | (level << 60) | (i << 40) | (j << 20) | k


@dataclass(frozen=True)
class MapBoundaryConfig(Checked):
    """Which pieces are boundaries and how they are inflated.

    Attributes
    ----------
    detect_range_m : float
        A piece is a boundary when one of its voxels is within this distance of the
        vehicle [m] (perception's ``threshold_m``, the paper's 4 m).
    inflate_m : float
        Vehicle radius + safety margin added to every sphere [m] (perception's
        ``vehicle_radius_m + safety_margin_m``, 0.35 + 0.3).
    open_band_m : float
        Openings seen free are kept open (module docstring, "Openings seen free") where
        their middle lies within this height above or below the vehicle [m]: the local
        path search reaches 1 m up and down, guidance aims no steeper than 12°; farther
        openings keep their whole spheres (the cost stays bounded).
    max_voxel_spheres : int
        Most single-voxel spheres one frame's openings may add (their cost in the cone
        rule); beyond it a piece keeps its coarser sphere (the opening stays closed there).
    """

    detect_range_m: float = bounded(4.0, "m", gt=0)
    inflate_m: float = bounded(0.65, "m", gt=0)
    open_band_m: float = bounded(1.0, "m", ge=0)
    max_voxel_spheres: int = bounded(64, integer=True, ge=0)


@dataclass(frozen=True)
class MapBoundary:
    """One piece's collision safety boundary (a :class:`~companion.guidance.cone.SphereLike`).

    Attributes
    ----------
    center_ned_m : tuple of 3 float
        Sphere centre [m, NED].
    radius_m : float
        Inflated radius [m].
    track_key : int
        Stable id of the piece (see :func:`track_key`).
    piece_radius_m : float
        Radius enclosing the piece's voxels, about their centroid [m].
    blind_depth_m : float
        Blind-spot depth behind the piece included in the sphere [m].
    nearest_m : float
        Vehicle to the piece's nearest voxel centre [m].
    goal_gap_m : float
        Goal to the piece's nearest voxel surface (centre distance − half a voxel) [m].
    trimmed : bool
        The sphere was trimmed to leave a reachable goal outside.
    """

    center_ned_m: tuple[float, float, float]
    radius_m: float
    track_key: int
    piece_radius_m: float
    blind_depth_m: float
    nearest_m: float
    goal_gap_m: float
    trimmed: bool = False
    piece_center_ned_m: tuple[float, float, float] | None = None
    """Centroid of the piece's voxels [m, NED] (None: the sphere's centre)."""
    solid_ned_m: tuple[float, float, float, float] | None = None
    """An opened piece's solid extent ``(north, east, down, radius)`` [m]: the sphere of
    the piece and its blind spot it had before opening (None: from this sphere)."""


def _boundaries_of(
    space: KnownSpace,
    pieces: Pieces,
    level: int,
    pos: np.ndarray,
    goal: np.ndarray,
    goal_free: bool,
    config: MapBoundaryConfig,
) -> list[MapBoundary]:
    """Spheres of ``pieces`` (module docstring); trimmed where a reachable goal is inside."""
    half_voxel = 0.5 * space.config.voxel_m
    blind = space.unseen_runs_m(pieces.centroid_ned_m, pos, space.config.blind_depth_m)
    out = []
    for m in range(len(pieces)):
        c = pieces.centroid_ned_m[m]
        r = float(pieces.radius_m[m])
        bearing = c - pos
        dist = math.sqrt(float(bearing @ bearing))
        e = float(blind[m]) if dist > 1e-9 else 0.0
        centre = c + (0.5 * e / dist) * bearing if e > 0.0 else c.copy()
        radius = r + 0.5 * e + config.inflate_m
        gap = max(float(pieces.nearest_to_point_m[m]) - half_voxel, 0.0)
        trimmed = False
        to_goal = float(np.linalg.norm(goal - centre))
        if (
            level >= 1
            and to_goal < radius
            and not _blocks(gap, goal_free, in_shadow(pos, goal, c, r), config, space)
        ):
            d = float(np.linalg.norm(goal - c))
            if d - _TRIM_EPS_M >= r:  # the trimmed sphere still encloses the voxels
                centre, radius, e, trimmed = c.copy(), d - _TRIM_EPS_M, 0.0, True
        out.append(
            MapBoundary(
                center_ned_m=tuple(float(x) for x in centre),
                radius_m=float(radius),
                track_key=track_key(level, pieces.key[m]),
                piece_radius_m=r,
                blind_depth_m=float(e),
                nearest_m=float(pieces.nearest_m[m]),
                goal_gap_m=gap,
                trimmed=trimmed,
                piece_center_ned_m=tuple(float(x) for x in c),
            )
        )
    return out


def _open_gaps(boundaries: list[MapBoundary], config: MapBoundaryConfig) -> list[MapBoundary]:
    """Shrink the spheres that close a passable gap to their pieces (see "Gaps stay open")."""
    if not boundaries:
        return boundaries
    centre = np.array([b.center_ned_m for b in boundaries])
    radius = np.array([b.radius_m for b in boundaries])
    piece = np.array([b.piece_center_ned_m or b.center_ned_m for b in boundaries])
    piece_r = np.array([b.piece_radius_m for b in boundaries])
    own_r = piece_r + config.inflate_m
    overlap = np.linalg.norm(centre[:, None, :] - centre[None, :, :], axis=2)
    overlap = overlap < radius[:, None] + radius[None, :]
    ab = piece[None, :, :] - piece[:, None, :]  # (n, n, 3)
    length = np.linalg.norm(ab, axis=2)
    passable = np.triu(overlap & (length - own_r[:, None] - own_r[None, :] >= 0.0), k=1)
    opened = np.zeros(len(boundaries), dtype=bool)
    a, b = np.nonzero(passable)
    if a.size:
        # no third piece's inflated sphere reaches the opening between the two inflated
        # pieces on the segment a → b (the rest of one wall fills it)
        seg, seg_len = ab[a, b], length[a, b]  # (p, 3), (p,)
        t = np.einsum("pnk,pk->pn", piece[None, :, :] - piece[a][:, None, :], seg)
        t0, t1 = own_r[a] / seg_len, 1.0 - own_r[b] / seg_len
        t = np.clip(t / (seg_len * seg_len)[:, None], t0[:, None], t1[:, None])
        nearest = piece[a][:, None, :] + t[:, :, None] * seg[:, None, :]
        blocked = np.linalg.norm(piece[None, :, :] - nearest, axis=2) < own_r[None, :]
        blocked[np.arange(a.size), a] = False
        blocked[np.arange(a.size), b] = False
        open_pair = ~blocked.any(axis=1)
        opened[a[open_pair]] = True
        opened[b[open_pair]] = True
    level0 = np.array([_decode_key(b.track_key)[0] == 0 for b in boundaries])
    opened &= level0  # sub-pieces (near the goal) stay whole
    return [_own_sphere(b, config) if o else b for b, o in zip(boundaries, opened, strict=True)]


def _own_sphere(b: MapBoundary, config: MapBoundaryConfig) -> MapBoundary:
    """The piece's own inflated sphere: centroid, ``r + inflate_m``; its solid extent
    (:func:`solid_extent`) stays the whole piece and blind spot it was before."""
    c = b.piece_center_ned_m or b.center_ned_m
    solid = (*b.center_ned_m, b.piece_radius_m + 0.5 * b.blind_depth_m)
    return dataclasses.replace(
        b, center_ned_m=c, radius_m=b.piece_radius_m + config.inflate_m, solid_ned_m=solid
    )


def _decode_key(key: int) -> tuple[int, np.ndarray]:
    """Inverse of :func:`track_key`: ``(level, cube)``."""
    mask = (1 << 20) - 1
    level = (key >> 60) & 3
    cube = np.array([((key >> s) & mask) - _KEY_OFFSET for s in (40, 20, 0)], dtype=np.int64)
    return level, cube


def map_boundaries(
    space: KnownSpace, pos_ned_m, goal_ned_m, config: MapBoundaryConfig | None = None
) -> tuple[MapBoundary, ...]:
    """Boundary spheres of the OCCUPIED space near the vehicle (module docstring).

    Parameters
    ----------
    space : KnownSpace
        The map, after this frame's update.
    pos_ned_m, goal_ned_m : array_like, shape (3,)
        Vehicle position and goal [m, NED].
    config : MapBoundaryConfig, optional

    Returns
    -------
    tuple of MapBoundary
        Ordered by ``track_key``.
    """
    cfg = MapBoundaryConfig() if config is None else config
    pos = np.asarray(pos_ned_m, dtype=float)
    goal = np.asarray(goal_ned_m, dtype=float)
    pieces = space.pieces(pos, cfg.detect_range_m, goal)
    if len(pieces) == 0:
        return ()
    goal_free = space.state_at(goal) == int(FREE)
    boundaries = _boundaries_of(space, pieces, 0, pos, goal, goal_free, cfg)
    # a reachable goal inside a piece's sphere: that piece is replaced by its sub-pieces
    split = {
        b.track_key
        for b in boundaries
        if float(np.linalg.norm(goal - np.asarray(b.center_ned_m))) < b.radius_m
        and not _blocks(b.goal_gap_m, goal_free, _shadows_goal(b, pos, goal), cfg, space)
    }
    if split:
        # every sub-piece of a split piece: reach out by the piece's diagonal
        half = space.config.piece_vox // 2
        diag_m = space.config.piece_vox * space.config.voxel_m * math.sqrt(3.0)
        sub = space.pieces(pos, cfg.detect_range_m + diag_m, goal, piece_vox=half)
        parents = np.floor_divide(sub.key, 2)
        keep = np.array([track_key(0, p) in split for p in parents], dtype=bool)
        sub = Pieces(*(np.asarray(f)[keep] for f in _fields(sub)))
        boundaries = [b for b in boundaries if b.track_key not in split]
        boundaries += _boundaries_of(space, sub, 1, pos, goal, goal_free, cfg)
    boundaries = _open_gaps(boundaries, cfg)
    boundaries = _keep_open(space, boundaries, pos, goal, cfg)
    return tuple(sorted(boundaries, key=lambda b: b.track_key))


def goal_surely_blocked(boundaries, goal_ned_m, config: MapBoundaryConfig | None = None) -> bool:
    """Whether a boundary holding the goal holds it for certain: the goal within
    ``inflate_m`` of that piece's seen surface (``goal_gap_m``), not only in its blind spot
    (which may turn out free once seen). False when no boundary holds the goal."""
    cfg = MapBoundaryConfig() if config is None else config
    goal = np.asarray(goal_ned_m, dtype=float)
    return any(
        b.goal_gap_m < cfg.inflate_m
        for b in boundaries
        if float(np.linalg.norm(goal - np.asarray(b.center_ned_m))) < b.radius_m
    )


def solid_extent(boundaries) -> np.ndarray:
    """Where each boundary's obstacle may be: ``(n, 4)`` rows ``(north, east, down,
    radius)`` [m], the sphere without its inflation (the piece and its blind spot, Fig. 4;
    an opened piece's row is the piece and blind spot it had before opening).

    The safety envelope's near-field excuse (unseen space beside the vehicle's path that
    no forward camera could have shown) never applies inside these spheres
    (:meth:`companion.known_space.KnownSpace.free_distance_m`).
    """
    out = np.empty((len(boundaries), 4))
    for n, b in enumerate(boundaries):
        solid = getattr(b, "solid_ned_m", None)
        if solid is not None:
            out[n] = solid
            continue
        out[n, :3] = b.center_ned_m
        out[n, 3] = b.piece_radius_m + 0.5 * b.blind_depth_m
    return out


# -- openings seen free ------------------------------------------------------------------


def _keep_open(
    space: KnownSpace,
    boundaries: list[MapBoundary],
    pos: np.ndarray,
    goal: np.ndarray,
    config: MapBoundaryConfig,
) -> list[MapBoundary]:
    """Boundaries made smaller where they hold a point of an opening seen free
    (:mod:`companion.guidance.openings`; module docstring, "Openings seen free")."""
    if not boundaries:
        return boundaries
    c = space.config
    reach = config.detect_range_m + c.piece_vox * c.voxel_m * math.sqrt(3.0)
    points = opening_points(
        space, pos, inflate_m=config.inflate_m, widest_m=2.0 * max(b.radius_m for b in boundaries),
        reach_m=reach, near_m=config.detect_range_m, band_m=config.open_band_m,
    )  # fmt: skip
    if len(points) == 0:
        return boundaries
    centre = np.array([b.center_ned_m for b in boundaries])
    radius = np.array([b.radius_m for b in boundaries])
    goal_in = np.linalg.norm(centre - goal, axis=1) < radius
    trimmed = np.array([b.trimmed for b in boundaries])
    hold = covers(centre, radius, points) & ~goal_in & ~trimmed
    out = [b for b, h in zip(boundaries, hold, strict=True) if not h]
    owns = [
        b if b.solid_ned_m is not None else _own_sphere(b, config)
        for b in np.array(boundaries, dtype=object)[hold]
    ]
    if not owns:
        return out
    own_hold = covers(
        np.array([b.center_ned_m for b in owns]), np.array([b.radius_m for b in owns]), points
    )
    out += [b for b, h in zip(owns, own_hold, strict=True) if not h]
    split = [b for b, h in zip(owns, own_hold, strict=True) if h]
    if not split:
        return out
    keys = [_decode_key(b.track_key) for b in split]
    refined, replaced = split_for_openings(
        space, pos, goal, np.array([k[0] for k in keys]), np.array([k[1] for k in keys]), points,
        inflate_m=config.inflate_m, reach_m=reach, max_voxel_spheres=config.max_voxel_spheres,
    )  # fmt: skip
    out += [b for b, r in zip(split, replaced, strict=True) if not r]
    if len(refined) == 0:
        return out
    e = space.unseen_runs_m(refined.centre_ned_m, pos, c.blind_depth_m)
    bearing = refined.centre_ned_m - pos
    dist = np.maximum(np.linalg.norm(bearing, axis=1), 1e-9)
    solid = np.column_stack(
        [
            refined.centre_ned_m + (0.5 * e / dist)[:, None] * bearing,
            refined.piece_radius_m + 0.5 * e,
        ]
    )
    rows = zip(
        refined.level.tolist(), refined.cube, refined.centre_ned_m.tolist(),
        refined.piece_radius_m.tolist(), e.tolist(), refined.nearest_m.tolist(),
        refined.goal_gap_m.tolist(), solid.tolist(), strict=True,
    )  # fmt: skip
    for level, cube, centre_m, r, depth, nearest, gap, solid_m in rows:
        out.append(
            MapBoundary(
                center_ned_m=tuple(centre_m),
                radius_m=r + config.inflate_m,
                track_key=track_key(level, cube),
                piece_radius_m=r,
                blind_depth_m=depth,
                nearest_m=nearest,
                goal_gap_m=gap,
                piece_center_ned_m=tuple(centre_m),
                solid_ned_m=tuple(solid_m),
            )
        )
    return out


def _blocks(
    gap_m: float, goal_free: bool, shadowed: bool, config: MapBoundaryConfig, space: KnownSpace
) -> bool:
    """Does a piece whose nearest voxel surface is ``gap_m`` from the goal block it?

    Within ``inflate_m`` of the seen surface: always. Farther, within the blind spot's
    depth: when the goal is unseen (not FREE) *and* lies behind the piece as the vehicle
    looks at it (``shadowed``, :func:`in_shadow`), since only there can it be inside the
    obstacle (Fig. 4). An unseen goal beside or in front of the seen surface is not in
    its blind spot: it is reached once seen free, the safety envelope keeping every
    setpoint in space seen free on the way (issue 36, vertical-123: a goal 1.65 m in
    front of a wall, above the camera's view, was held as "unreachable")."""
    if gap_m < config.inflate_m:
        return True  # too near the real surface
    # an unseen goal behind the surface, within the blind spot's depth, may be inside it
    return not goal_free and shadowed and gap_m < config.inflate_m + space.config.blind_depth_m


def in_shadow(pos_ned_m, goal_ned_m, centroid_ned_m, piece_radius_m: float) -> bool:
    """Whether a piece (voxels within ``piece_radius_m`` of ``centroid_ned_m``) hides
    the goal from the vehicle: the straight line of sight from ``pos_ned_m`` to
    ``goal_ned_m`` passes within ``piece_radius_m`` of the centroid, and the centroid lies
    before the goal along it (in front of the vehicle). The blind spot of Fig. 4 is
    behind a surface as seen; a goal out of every such shadow is not in one."""
    pos = np.asarray(pos_ned_m, dtype=float)
    sight = np.asarray(goal_ned_m, dtype=float) - pos
    length = math.sqrt(float(sight @ sight))
    to_c = np.asarray(centroid_ned_m, dtype=float) - pos
    if length < 1e-9:
        return False
    along = float(to_c @ sight) / length
    if not 0.0 < along < length:
        return False
    off2 = float(to_c @ to_c) - along * along
    return off2 < float(piece_radius_m) ** 2


def _shadows_goal(b: MapBoundary, pos: np.ndarray, goal: np.ndarray) -> bool:
    centre = b.piece_center_ned_m or b.center_ned_m
    return in_shadow(pos, goal, centre, b.piece_radius_m)


def _fields(p: Pieces) -> tuple[np.ndarray, ...]:
    return (p.key, p.centroid_ned_m, p.radius_m, p.n_voxels, p.nearest_m, p.nearest_to_point_m)
