"""Openings seen free stay open: the boundary spheres near one made smaller (issue 36).

The boundary spheres of :mod:`companion.guidance.map_boundaries` enclose a map piece (a
cube of 1.2 m), its blind spot (Fig. 4) and the vehicle's radius and margin. Seen from a
stereo camera, the edges of a 2.7 m opening in a wall are pieces whose spheres reach
1.1–1.5 m into it, and the opening the map has seen free (2.0–2.2 m between its occupied
voxels) is closed to the cone rule and to the path search alike: the vehicle paced along
the wall for a minute (passage Monte Carlo seeds 0 and 112).

Where the openings are (:func:`opening_points`)
-----------------------------------------------
For every pair of pieces side by side (their voxels' boxes overlap or touch in height:
a way through them is level, as the vehicle flies openings; a piece above another, an
obstacle over the ground, is not an opening here) whose boxes are at least
``2 · inflate_m`` apart (the vehicle and its margins fit between the real surfaces), the
middle between the boxes' nearest faces is an opening's middle when it is a middle
indeed, and seen free:

* its voxel is FREE (seen free; never unknown space);
* no OCCUPIED or TENTATIVE voxel lies nearer than half the pair's gap, less a voxel (the
  boxes' rounding), nor nearer than ``inflate_m`` (the path search's clearance, measured
  to the voxels' faces): the two pieces are its nearest surfaces, and nothing stands in
  the opening;
* it lies within the detection range of the vehicle and ``band_m`` of its height (the cost
  bound: the path search reaches 1 m up and down).

With each middle go the centres of the voxels about it (3 × 3 × 3) that no sphere of a
single voxel can cover (at least ``inflate_m`` plus a voxel's half diagonal less half a
voxel from every OCCUPIED or TENTATIVE voxel's face): the voxels the path search crosses.

Smaller spheres (:func:`split_for_openings`)
-------------------------------------------
A boundary that holds one of these points is made smaller, one step at a time while it
still holds one (:mod:`~companion.guidance.map_boundaries` drops the blind spot first):

1. the piece's sub-pieces (cubes of half the edge), each its own inflated sphere;
2. a sub-piece that still holds a point: its voxels nearest the openings (within a voxel
   of the nearest), one sphere each, and one sphere for the rest of its voxels (track key
   level 3, the sub-piece's cube); when the rest's sphere still holds a point, every voxel
   on its own. At most ``max_voxel_spheres`` single voxels per frame (nearest sub-pieces
   first); beyond it a sub-piece keeps its sphere and the opening stays closed there.

Every sphere still encloses its voxels (whole cells) plus ``inflate_m``, so no opening
narrower than ``2 · inflate_m`` between the voxels' faces ever opens, and nothing the map
has seen is left out. What is dropped is the blind spot's growth of the spheres (it stays
in their solid extent, where the envelope excuses nothing, and it is unknown space, where
no carrot and no path go). The bound: a sphere of one voxel reaches ``inflate_m`` plus
``(√3 − 1)/2`` of a voxel beyond the voxel's face (0.723 m), so an opening stays open to
the cone rule from ``2 · 0.723`` m (1.6 m on the 0.2 m grid) and to the path search, whose
path runs through voxel centres, from 1.8 m on the grid. Stereo maps a 2.5 m opening
2.0–2.2 m wide.

Pure: the map is read, never written; no clock, no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from companion.guidance.known_path import _state
from companion.known_space import FREE, OCCUPIED, TENTATIVE, KnownSpace, Pieces

__all__ = ["Refined", "opening_points", "split_for_openings"]

_NEIGHBOURS = np.stack(np.meshgrid(*[np.arange(-1, 2)] * 3, indexing="ij"), -1).reshape(-1, 3)
_OFFSET = 1 << 19  # cube indices within ±2^19, as map_boundaries.track_key


@dataclass(frozen=True, eq=False)
class Refined:
    """Smaller spheres, one row each (own inflated spheres, no blind-spot growth).

    Attributes
    ----------
    level : ndarray of int, shape (n,)
        Track-key level: 1 sub-piece, 2 voxel, 3 the rest of a sub-piece's voxels.
    cube : ndarray of int64, shape (n, 3)
        The cube of that level (level 3: the sub-piece's).
    centre_ned_m : ndarray, shape (n, 3)
        Centroid of the voxels [m, NED] (the sphere's centre).
    piece_radius_m : ndarray, shape (n,)
        Radius about the centroid enclosing the voxels' cells [m].
    nearest_m, goal_gap_m : ndarray, shape (n,)
        Vehicle to the nearest voxel centre; goal to the nearest voxel face [m].
    """

    level: np.ndarray
    cube: np.ndarray
    centre_ned_m: np.ndarray
    piece_radius_m: np.ndarray
    nearest_m: np.ndarray
    goal_gap_m: np.ndarray

    def __len__(self) -> int:
        return int(self.level.shape[0])


def opening_points(
    space: KnownSpace,
    pos_ned_m: np.ndarray,
    *,
    inflate_m: float,
    widest_m: float,
    reach_m: float,
    near_m: float,
    band_m: float,
) -> np.ndarray:
    """Points of the openings seen free near the vehicle (module docstring), ``(k, 3)``
    [m, NED]. ``widest_m``: pairs farther apart are not considered (no sphere bridges
    them); ``reach_m``: the pieces considered (a voxel within it of the vehicle);
    ``near_m``, ``band_m``: how far from the vehicle, and above or below it, a middle may
    lie."""
    none = np.zeros((0, 3))
    c = space.config
    pos = np.asarray(pos_ned_m, dtype=float)
    pieces = space.pieces(pos, reach_m)
    if len(pieces) < 2:
        return none
    box = _cube_boxes(space.grid, space.origin_vox, c.piece_vox, pieces.key)
    lo, hi = box[:, :3], box[:, 3:] + 1  # each piece's voxel cells [voxel index]
    sep = np.maximum(lo[None, :, :] - hi[:, None, :], lo[:, None, :] - hi[None, :, :])
    gap_m = np.linalg.norm(np.maximum(sep, 0), axis=2) * c.voxel_m
    side_by_side = sep[:, :, 2] <= 0  # their heights overlap or touch: a way through, level
    pairs = (gap_m >= 2.0 * inflate_m) & (gap_m < widest_m) & side_by_side
    a, b = np.nonzero(np.triu(pairs, k=1))
    if a.size == 0:
        return none
    # per axis, the middle between the boxes' nearest faces (of their overlap if they overlap)
    mid = 0.5 * (np.maximum(lo[a], lo[b]) + np.minimum(hi[a], hi[b])) * c.voxel_m
    half_gap = 0.5 * gap_m[a, b]
    near = (np.abs(mid[:, 2] - pos[2]) <= band_m) & (np.linalg.norm(mid - pos, axis=1) <= near_m)
    mid, half_gap = mid[near], half_gap[near]
    if len(mid) == 0:
        return none
    # a middle of the opening, not a point beside one of its edges: no other piece's box
    # nearer than the pair (less a voxel), and no surface within the clearance
    to_box = np.linalg.norm(
        np.maximum(
            np.maximum(lo[None] * c.voxel_m - mid[:, None], mid[:, None] - hi[None] * c.voxel_m),
            0.0,
        ),
        axis=2,
    )
    middle = np.all(to_box >= (half_gap - c.voxel_m)[:, None] - 1e-9, axis=1)
    mid = np.unique(np.round(mid[middle], 6), axis=0)
    free_m = inflate_m + (0.5 * math.sqrt(3.0) - 0.5) * c.voxel_m  # a voxel's sphere's reach
    mid = mid[_clear_points(space.grid, space.origin_vox, c.voxel_m, mid, free_m)]
    if len(mid) == 0:
        return none
    cells = np.floor(mid / c.voxel_m)[:, None, :] + _NEIGHBOURS[None, :, :]
    cells = (np.unique(cells.reshape(-1, 3), axis=0) + 0.5) * c.voxel_m
    cells = cells[_clear_points(space.grid, space.origin_vox, c.voxel_m, cells, free_m)]
    return np.vstack([mid, cells])


def covers(centre_ned_m: np.ndarray, radius_m: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Per sphere (rows of ``centre_ned_m``, ``radius_m``): whether it holds one of
    ``points`` (strictly inside)."""
    centre = np.asarray(centre_ned_m, dtype=float).reshape(-1, 3)
    if len(points) == 0 or len(centre) == 0:
        return np.zeros(len(centre), dtype=bool)
    d = centre[:, None, :] - points[None, :, :]
    r = np.asarray(radius_m, dtype=float).reshape(-1)
    return np.any(np.einsum("nkj,nkj->nk", d, d) < (r * r)[:, None], axis=1)


def split_for_openings(
    space: KnownSpace,
    pos_ned_m: np.ndarray,
    goal_ned_m: np.ndarray,
    parent_level: np.ndarray,
    parent_cube: np.ndarray,
    points: np.ndarray,
    *,
    inflate_m: float,
    reach_m: float,
    max_voxel_spheres: int,
) -> tuple[Refined, np.ndarray]:
    """The smaller spheres (module docstring, steps 1 and 2) of the pieces
    ``parent_cube`` (rows, at ``parent_level`` 0 or 1) whose own spheres hold one of
    ``points``; and, per parent, whether it was replaced (False: it keeps its own sphere).
    """
    c = space.config
    pos = np.asarray(pos_ned_m, dtype=float)
    goal = np.asarray(goal_ned_m, dtype=float)
    pv, sub = c.piece_vox, c.piece_vox // 2
    parent_level = np.asarray(parent_level, dtype=int)
    parent_cube = np.asarray(parent_cube, dtype=np.int64).reshape(-1, 3)
    replaced = np.zeros(len(parent_level), dtype=bool)
    out: list[Refined] = []
    # step 1: level-0 pieces as their sub-pieces
    cand_cube = [parent_cube[parent_level == 1]]
    cand_parent = [np.flatnonzero(parent_level == 1)]  # parent row, or -1: a sub-piece
    fallback = _empty()  # the own spheres of the sub-pieces that go on to step 2
    top = np.flatnonzero(parent_level == 0)
    if top.size and 1 <= sub < pv:
        s1 = space.pieces(pos, reach_m, goal, piece_vox=sub)
        rows = _rows(s1, np.isin(_code(s1.key // (pv // sub)), _code(parent_cube[top])))
        replaced[top] = True
        hold = covers(rows.centroid_ned_m, rows.radius_m + inflate_m, points)
        out.append(_refined(rows, ~hold, 1, rows.key, c.voxel_m))
        fallback = _refined(rows, hold, 1, rows.key, c.voxel_m)
        cand_cube.append(rows.key[hold])
        cand_parent.append(np.full(int(np.count_nonzero(hold)), -1))
    cubes = np.vstack(cand_cube)
    owner = np.concatenate(cand_parent)
    if len(cubes):
        peeled, done = _peel(space, pos, goal, cubes, points, inflate_m, reach_m, max_voxel_spheres)
        out.append(peeled)
        replaced[owner[(owner >= 0) & done]] = True
        out.append(_subset(fallback, ~done[owner < 0]))  # over the budget: own spheres
    out = [r for r in out if len(r)]
    if not out:
        return _empty(), replaced
    return Refined(*(np.concatenate([getattr(r, f) for r in out]) for f in _FIELDS)), replaced


_FIELDS = ("level", "cube", "centre_ned_m", "piece_radius_m", "nearest_m", "goal_gap_m")


def _peel(space, pos, goal, cubes, points, inflate_m, reach_m, budget):
    """Step 2 for the sub-pieces ``cubes``: (their voxel and rest spheres, per cube
    whether it was peeled within the budget)."""
    c = space.config
    sub = c.piece_vox // 2
    voxel = c.voxel_m
    n = len(cubes)
    v = space.pieces(pos, reach_m, goal, piece_vox=1)
    codes = _code(cubes)
    sorter = np.argsort(codes)
    vcode = _code(v.key // sub)
    pos_in = np.searchsorted(codes[sorter], vcode)
    pos_in = np.clip(pos_in, 0, n - 1)
    g = sorter[pos_in]
    mine = codes[g] == vcode
    vx = _rows(v, mine)
    g = g[mine]
    d = vx.centroid_ned_m[:, None, :] - points[None, :, :]
    to_mid = np.sqrt(np.min(np.einsum("vkj,vkj->vk", d, d), axis=1))
    gmin = np.full(n, np.inf)
    np.minimum.at(gmin, g, to_mid)
    peel = to_mid < gmin[g] + voxel
    # one sphere about each cube's rest
    rest = ~peel
    count = np.bincount(g[rest], minlength=n).astype(float)
    centroid = np.zeros((n, 3))
    np.add.at(centroid, g[rest], vx.centroid_ned_m[rest])
    centroid /= np.maximum(count, 1.0)[:, None]
    radius = np.zeros(n)
    np.maximum.at(
        radius,
        g[rest],
        np.linalg.norm(vx.centroid_ned_m[rest] - centroid[g[rest]], axis=1) + vx.radius_m[rest],
    )
    has_rest = count > 0
    rest_holds = has_rest & covers(centroid, radius + inflate_m, points)
    peel |= rest_holds[g]  # every voxel on its own
    has_rest &= ~rest_holds
    n_peel = np.bincount(g[peel], minlength=n)
    nearest = np.full(n, np.inf)
    np.minimum.at(nearest, g, vx.nearest_m)
    to_goal = np.full(n, np.inf)
    np.minimum.at(to_goal, g, vx.nearest_to_point_m)
    order = np.argsort(nearest, kind="stable")
    done = np.zeros(n, dtype=bool)
    done[order[np.cumsum(n_peel[order]) <= budget]] = True
    single = _refined(vx, peel & done[g], 2, vx.key, voxel)
    keep = has_rest & done
    rest_rows = Refined(
        level=np.full(int(np.count_nonzero(keep)), 3),
        cube=cubes[keep],
        centre_ned_m=centroid[keep],
        piece_radius_m=radius[keep],
        nearest_m=nearest[keep],
        goal_gap_m=np.maximum(to_goal[keep] - 0.5 * voxel, 0.0),
    )
    both = [r for r in (single, rest_rows) if len(r)]
    if not both:
        return _empty(), done
    return Refined(*(np.concatenate([getattr(r, f) for r in both]) for f in _FIELDS)), done


def _rows(p: Pieces, mask: np.ndarray) -> Pieces:
    fields = (p.key, p.centroid_ned_m, p.radius_m, p.n_voxels, p.nearest_m, p.nearest_to_point_m)
    return Pieces(*(np.asarray(f)[mask] for f in fields))


def _refined(p: Pieces, mask: np.ndarray, level: int, cube: np.ndarray, voxel_m: float) -> Refined:
    return Refined(
        level=np.full(int(np.count_nonzero(mask)), level),
        cube=np.asarray(cube)[mask],
        centre_ned_m=p.centroid_ned_m[mask],
        piece_radius_m=p.radius_m[mask],
        nearest_m=p.nearest_m[mask],
        goal_gap_m=np.maximum(p.nearest_to_point_m[mask] - 0.5 * voxel_m, 0.0),
    )


def _subset(r: Refined, index) -> Refined:
    return Refined(*(getattr(r, f)[index] for f in _FIELDS))


def _empty() -> Refined:
    z = np.zeros(0)
    return Refined(np.zeros(0, int), np.zeros((0, 3), np.int64), np.zeros((0, 3)), z, z, z)


def _code(keys: np.ndarray) -> np.ndarray:
    """One int64 per cube index row (as :func:`map_boundaries.track_key` packs them)."""
    k = np.asarray(keys, dtype=np.int64).reshape(-1, 3) + _OFFSET
    return (k[:, 0] << 40) | (k[:, 1] << 20) | k[:, 2]


@numba.njit(cache=True)
def _cube_boxes(grid, origin, piece, keys):
    """Per cube ``keys[m]`` (edge ``piece`` voxels): the least and greatest global voxel
    index of its OCCUPIED voxels in the grid, ``(lo0, lo1, lo2, hi0, hi1, hi2)``."""
    out = np.empty((keys.shape[0], 6), np.int64)
    lo = np.empty(3, np.int64)
    hi = np.empty(3, np.int64)
    for m in range(keys.shape[0]):
        for a in range(3):
            lo[a] = max(keys[m, a] * piece - origin[a], 0)
            hi[a] = min((keys[m, a] + 1) * piece - origin[a], grid.shape[a])
            out[m, a] = 1 << 40
            out[m, 3 + a] = -(1 << 40)
        for i in range(lo[0], hi[0]):
            for j in range(lo[1], hi[1]):
                for k in range(lo[2], hi[2]):
                    if grid[i, j, k] != OCCUPIED:
                        continue
                    out[m, 0] = min(out[m, 0], i + origin[0])
                    out[m, 1] = min(out[m, 1], j + origin[1])
                    out[m, 2] = min(out[m, 2], k + origin[2])
                    out[m, 3] = max(out[m, 3], i + origin[0])
                    out[m, 4] = max(out[m, 4], j + origin[1])
                    out[m, 5] = max(out[m, 5], k + origin[2])
    return out


@numba.njit(cache=True)
def _clear_points(grid, origin, voxel, points, clear_m):
    """Per point ``points[m]`` [m, NED]: its voxel FREE and no OCCUPIED or TENTATIVE voxel
    nearer than ``clear_m``, measured to the voxel's face (centre distance less half a
    voxel: the path search's clearance)."""
    out = np.zeros(points.shape[0], np.bool_)
    reach = clear_m + 0.5 * voxel
    n = math.ceil(reach / voxel) + 1
    for m in range(points.shape[0]):
        px, py, pz = points[m, 0], points[m, 1], points[m, 2]
        gx = math.floor(px / voxel) - origin[0]
        gy = math.floor(py / voxel) - origin[1]
        gz = math.floor(pz / voxel) - origin[2]
        if _state(grid, gx, gy, gz) != FREE:
            continue
        ok = True
        for i in range(gx - n, gx + n + 1):
            dx = (i + origin[0] + 0.5) * voxel - px
            for j in range(gy - n, gy + n + 1):
                dy = (j + origin[1] + 0.5) * voxel - py
                for k in range(gz - n, gz + n + 1):
                    s = _state(grid, i, j, k)
                    if s != OCCUPIED and s != TENTATIVE:
                        continue
                    dz = (k + origin[2] + 0.5) * voxel - pz
                    if dx * dx + dy * dy + dz * dz < reach * reach:
                        ok = False
        out[m] = ok
    return out


def warm_up() -> None:
    """Compile (or load from numba's cache) the kernels once per process."""
    grid = np.zeros((8, 8, 8), np.int8)
    grid[4, :, :] = OCCUPIED
    keys = np.zeros((1, 3), np.int64)
    _cube_boxes(grid, np.zeros(3, np.int64), 6, keys)
    _clear_points(grid, np.zeros(3, np.int64), 0.2, np.full((1, 3), 0.3), 0.65)
