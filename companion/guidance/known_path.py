"""A path through space seen free: grid search over the known-space map (issue 36).

The paper's rule (§5: collision cone, aiming point Eq. 28) stays the primary one. Its
cones are spheres seen from afar: the spheres at the two edges of an opening the vehicle
fits through subtend cones that overlap, so the cone rule finds no admissible direction
through it, or leads round the whole obstacle. The known-space map
(:mod:`companion.known_space`) knows better: it has seen the opening free. This module
searches that map for a path (the search kernels; following a path found and the rules
of when it leads are :mod:`companion.guidance.path_rules`), and guidance
(:mod:`companion.guidance.avoidance`) flies its first leg when the cone rule leaves no
admissible direction or closes a way the map shows open. The safety envelope still
bounds every carrot along the leg.

Pure: the map is passed in as its arrays (``grid``, ``origin_vox``, ``voxel_m``), no
clock or I/O. The search is a numba kernel (cached like the map's own).

Search
------
A* over the voxels of a box around the vehicle (``reach_m`` horizontally, ``reach_z_m``
up and down), 26-connected, a step costing its length with its vertical part weighted by
``vertical_weight`` (a multirotor keeps its altitude unless climbing is clearly shorter;
the camera sees little above the path), the heuristic the Euclidean distance to the goal
(admissible: weights ≥ 1). A voxel is *traversable* when

* it is FREE (seen free; UNKNOWN, TENTATIVE and OCCUPIED never are): no path through
  unknown space;
* no OCCUPIED or TENTATIVE voxel lies within ``clearance_m`` of its centre, measured to
  the voxel's face (centre distance minus half a voxel): the vehicle's radius plus the
  safety margin, the boundaries' inflation. An opening between two surfaces is passable
  when it is at least ``2 · clearance_m`` wide, plus up to one voxel of discretisation;
* its centre lies outside every sphere in ``spheres`` (the inflated collision safety
  boundaries guidance avoids, blind spots included: the unseen back of an obstacle is
  obstacle, Fig. 4);
* beyond ``near_field_m`` of the vehicle, the vehicle's section about its centre (an
  ellipse ``section_radius_m`` wide, ``section_half_height_m`` high, centre to centre)
  holds no UNKNOWN voxel: the safety envelope certifies the same section
  (:func:`companion.guidance.envelope.envelope_step`), so a path along which it would not
  move is not offered. Within the near field the sides are excused as the envelope
  excuses them (beside the vehicle the camera cannot look).

The vehicle's own voxel is always traversable (it is there). When the goal's voxel is
reached the path ends there; otherwise at the expanded voxel nearest the goal (ties: the
shorter path), a *partial* path to the edge of what is known. The search ends early once
every way still open is ``slack_m`` longer than the best found, and after
``max_expansions`` voxels (the per-frame budget). Clearance from surfaces is stamped once
per search from the OCCUPIED voxels near the box (cost ∝ the surface seen).

First leg
---------
The farthest path voxel, no more than ``leg_max_m`` along the path, that the vehicle sees
in a straight line: every half-voxel sample of the segment from the vehicle lies in a
traversable voxel (or the vehicle's own). Guidance aims along it.

Following a path found, and when it leads instead of the cone rule, are
:mod:`companion.guidance.path_rules`.
"""

from __future__ import annotations

import functools
import heapq
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np

from companion.known_space import FREE, OCCUPIED, TENTATIVE, UNKNOWN
from protocols.config import bounded, check_fields, dataclass_from_mapping

__all__ = [
    "KnownPath",
    "KnownPathConfig",
    "plan_known_path",
]


@dataclass(frozen=True)
class KnownPathConfig:
    """Parameters of the known-space path search (named assumptions, SI units).

    Attributes
    ----------
    clearance_m : float
        Least distance from the path's voxel centres to the face of an OCCUPIED or
        TENTATIVE voxel [m]: vehicle radius 0.35 + safety margin 0.3 (perception's
        inflation of the boundaries).
    section_radius_m, section_half_height_m : float
        The vehicle's section that must be seen free about each path voxel beyond the near
        field [m] (the safety envelope's: 0.35 wide, 0.2 high).
    near_field_m : float
        Within this distance of the vehicle the section's sides may be unknown [m] (the
        envelope's ``near_field_m``).
    reach_m, reach_z_m : float
        Half-extent of the search box about the vehicle, horizontal and vertical [m]
        (8: the map's range).
    vertical_weight : float
        Cost factor of vertical motion, ≥ 1.
    leg_max_m : float
        Longest first leg, measured along the path [m].
    max_expansions : int
        Most voxels expanded per search (its cost bound).
    slack_m : float
        The search ends once every way still open is this much longer (cost plus
        distance to the goal) than the best end found so far [m]: a partial path's end
        that costs a detour of more than this is not worth looking for.
    replan_frames : int
        A path found is followed (:func:`follow_known_path`) for up to this many map frames
        before the map is searched again (10: a third of a second at 30 Hz), while it stays
        valid; a new opening is found within that time.
    rejoin_m : float
        A path is followed only while the vehicle is within this distance of one of its
        voxels [m]; farther, it has left the path and the map is searched again.
    """

    clearance_m: float = bounded(0.65, "m", ge=0)
    section_radius_m: float = bounded(0.35, "m", ge=0)
    section_half_height_m: float = bounded(0.2, "m", ge=0)
    near_field_m: float = bounded(1.05, "m", ge=0)
    reach_m: float = bounded(8.0, "m", gt=0)
    reach_z_m: float = bounded(1.0, "m", gt=0)
    vertical_weight: float = bounded(2.0, ge=1)
    leg_max_m: float = bounded(4.0, "m", gt=0)
    max_expansions: int = bounded(20000, integer=True, ge=1)
    slack_m: float = bounded(5.0, "m", ge=0)
    replan_frames: int = bounded(10, integer=True, ge=1)
    rejoin_m: float = bounded(0.6, "m", gt=0)

    def __post_init__(self) -> None:
        check_fields(self)

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> KnownPathConfig:
        """Build from a mapping; unknown keys and values out of bounds raise
        :class:`~protocols.config.ConfigError` naming the key."""
        return dataclass_from_mapping(cls, values, "known_path")


@dataclass(frozen=True, eq=False)
class KnownPath:
    """A path through known-free space.

    Attributes
    ----------
    waypoints_ned_m : ndarray, shape (n, 3)
        Voxel centres from the vehicle's voxel to the path's end [m, NED] (the first row
        is the vehicle's own position).
    leg_end_ned_m : ndarray, shape (3,)
        End of the first leg [m, NED] (module docstring).
    reaches_goal : bool
        The path ends in the goal's voxel (else at the edge of what is known).
    end_to_goal_m : float
        Distance from the path's end to the goal [m].
    length_m : float
        Length of the path [m].
    expanded : int
        Voxels the search expanded.
    """

    waypoints_ned_m: np.ndarray
    leg_end_ned_m: np.ndarray
    reaches_goal: bool
    end_to_goal_m: float
    length_m: float
    expanded: int


def _offsets(rx_m: float, rz_m: float, voxel_m: float, face: bool) -> np.ndarray:
    """Integer voxel offsets within an ellipsoid (``rx_m`` horizontal, ``rz_m``
    vertical) of a voxel's centre; ``face``: measured to the other voxel's face (centre
    distance minus half a voxel, a sphere of ``rx_m``)."""
    if face:
        reach = rx_m + 0.5 * voxel_m
        n = math.ceil(reach / voxel_m)
        r = np.arange(-n, n + 1)
        i, j, k = np.meshgrid(r, r, r, indexing="ij")
        d = np.sqrt(i * i + j * j + k * k) * voxel_m
        keep = d < reach - 1e-9
    else:
        nx, nz = math.floor(rx_m / voxel_m), math.floor(rz_m / voxel_m)
        i, j, k = np.meshgrid(
            np.arange(-nx, nx + 1), np.arange(-nx, nx + 1), np.arange(-nz, nz + 1), indexing="ij"
        )
        q = ((i * i + j * j) * voxel_m**2) / max(rx_m, 1e-9) ** 2
        q = q + (k * k * voxel_m**2) / max(rz_m, 1e-9) ** 2
        keep = q <= 1.0 + 1e-9
    return np.ascontiguousarray(np.stack([i[keep], j[keep], k[keep]], axis=1), dtype=np.int64)


@numba.njit(cache=True)
def _state(grid, gx, gy, gz):
    if gx < 0 or gy < 0 or gz < 0:
        return UNKNOWN
    if gx >= grid.shape[0] or gy >= grid.shape[1] or gz >= grid.shape[2]:
        return UNKNOWN
    return grid[gx, gy, gz]


@numba.njit(cache=True)
def _near_surface(grid, lo, nx, ny, nz, occ_off):
    """Box voxels within the clearance of an OCCUPIED or TENTATIVE voxel: each such voxel
    near the box stamps its clearance ball (cost ∝ the surface seen, not the box)."""
    near = np.zeros(nx * ny * nz, np.bool_)
    m = 0
    for n in range(occ_off.shape[0]):
        m = max(m, abs(occ_off[n, 0]), abs(occ_off[n, 1]), abs(occ_off[n, 2]))
    x0, y0, z0 = max(lo[0] - m, 0), max(lo[1] - m, 0), max(lo[2] - m, 0)
    x1 = min(lo[0] + nx + m, grid.shape[0])
    y1 = min(lo[1] + ny + m, grid.shape[1])
    z1 = min(lo[2] + nz + m, grid.shape[2])
    for gx in range(x0, x1):
        for gy in range(y0, y1):
            for gz in range(z0, z1):
                s = grid[gx, gy, gz]
                if s != OCCUPIED and s != TENTATIVE:
                    continue
                for n in range(occ_off.shape[0]):
                    ix = gx + occ_off[n, 0] - lo[0]
                    iy = gy + occ_off[n, 1] - lo[1]
                    iz = gz + occ_off[n, 2] - lo[2]
                    if 0 <= ix < nx and 0 <= iy < ny and 0 <= iz < nz:
                        near[ix * ny * nz + iy * nz + iz] = True
    return near


@numba.njit(cache=True)
def _traversable(grid, gx, gy, gz, centre, spheres, sec_off, check_section):
    """1 when voxel (gx, gy, gz) of the grid, not near a surface, is traversable (module
    docstring), else 2."""
    if _state(grid, gx, gy, gz) != FREE:
        return 2
    for m in range(spheres.shape[0]):
        dx = centre[0] - spheres[m, 0]
        dy = centre[1] - spheres[m, 1]
        dz = centre[2] - spheres[m, 2]
        if dx * dx + dy * dy + dz * dz < spheres[m, 3] * spheres[m, 3]:
            return 2
    if check_section:
        for n in range(sec_off.shape[0]):
            s = _state(grid, gx + sec_off[n, 0], gy + sec_off[n, 1], gz + sec_off[n, 2])
            if s == UNKNOWN:
                return 2
    return 1


@numba.njit(cache=True)
def _search(
    grid, origin, voxel, pos, goal, box_xy, box_z, spheres, occ_off, sec_off, near_m,
    vertical_weight, max_expansions, leg_max_m, slack_m,
):  # fmt: skip
    """A* (module docstring). Returns (path voxel centres (n, 3), leg index, reached,
    expanded); the path's first row is the vehicle's position."""
    sx = math.floor(pos[0] / voxel) - origin[0]
    sy = math.floor(pos[1] / voxel) - origin[1]
    sz = math.floor(pos[2] / voxel) - origin[2]
    tx = math.floor(goal[0] / voxel) - origin[0]
    ty = math.floor(goal[1] / voxel) - origin[1]
    tz = math.floor(goal[2] / voxel) - origin[2]
    lo = np.array([sx - box_xy, sy - box_xy, sz - box_z])
    nx, ny, nz = 2 * box_xy + 1, 2 * box_xy + 1, 2 * box_z + 1
    size = nx * ny * nz
    trav = np.zeros(size, np.int8)  # 0 not asked, 1 traversable, 2 not
    near = _near_surface(grid, lo, nx, ny, nz, occ_off)
    for i in range(size):
        if near[i]:
            trav[i] = 2
    g = np.full(size, np.inf)
    parent = np.full(size, -1, np.int64)
    closed = np.zeros(size, np.bool_)
    start = (sx - lo[0]) * ny * nz + (sy - lo[1]) * nz + (sz - lo[2])
    trav[start] = 1
    g[start] = 0.0
    centre = np.empty(3)
    heap = [(0.0, 0.0, start)]
    best, best_h, best_g = start, np.inf, 0.0
    expanded = 0
    reached = False
    while len(heap) > 0 and expanded < max_expansions:
        fc, gc, node = heapq.heappop(heap)
        if closed[node]:
            continue
        if fc > best_g + best_h + slack_m:
            break  # every way still open is slack_m longer than the best one found
        closed[node] = True
        expanded += 1
        ix = node // (ny * nz)
        iy = (node // nz) % ny
        iz = node % nz
        gx, gy, gz = ix + lo[0], iy + lo[1], iz + lo[2]
        cx = (gx + origin[0] + 0.5) * voxel
        cy = (gy + origin[1] + 0.5) * voxel
        cz = (gz + origin[2] + 0.5) * voxel
        h = math.sqrt((cx - goal[0]) ** 2 + (cy - goal[1]) ** 2 + (cz - goal[2]) ** 2)
        if h < best_h - 1e-9 or (h < best_h + 1e-9 and gc < best_g):
            best, best_h, best_g = node, h, gc
        if gx == tx and gy == ty and gz == tz:
            reached = True
            best = node
            break
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                for dz in range(-1, 2):
                    if dx == 0 and dy == 0 and dz == 0:
                        continue
                    jx, jy, jz = ix + dx, iy + dy, iz + dz
                    if jx < 0 or jy < 0 or jz < 0 or jx >= nx or jy >= ny or jz >= nz:
                        continue
                    nb = jx * ny * nz + jy * nz + jz
                    if closed[nb]:
                        continue
                    hx, hy, hz = gx + dx, gy + dy, gz + dz
                    centre[0] = (hx + origin[0] + 0.5) * voxel
                    centre[1] = (hy + origin[1] + 0.5) * voxel
                    centre[2] = (hz + origin[2] + 0.5) * voxel
                    if trav[nb] == 0:
                        dp = math.sqrt(
                            (centre[0] - pos[0]) ** 2
                            + (centre[1] - pos[1]) ** 2
                            + (centre[2] - pos[2]) ** 2
                        )
                        trav[nb] = _traversable(
                            grid, hx, hy, hz, centre, spheres, sec_off, dp > near_m
                        )
                    if trav[nb] != 1:
                        continue
                    step = voxel * math.sqrt(dx * dx + dy * dy + (vertical_weight * dz) ** 2)
                    gn = gc + step
                    if gn < g[nb] - 1e-12:
                        g[nb] = gn
                        parent[nb] = node
                        hn = math.sqrt(
                            (centre[0] - goal[0]) ** 2
                            + (centre[1] - goal[1]) ** 2
                            + (centre[2] - goal[2]) ** 2
                        )
                        heapq.heappush(heap, (gn + hn, gn, nb))
    # the path, vehicle first
    n = 0
    node = best
    while node != -1:
        n += 1
        node = parent[node]
    path = np.empty((n, 3))
    node = best
    for k in range(n - 1, -1, -1):
        ix = node // (ny * nz)
        iy = (node // nz) % ny
        iz = node % nz
        path[k, 0] = (ix + lo[0] + origin[0] + 0.5) * voxel
        path[k, 1] = (iy + lo[1] + origin[1] + 0.5) * voxel
        path[k, 2] = (iz + lo[2] + origin[2] + 0.5) * voxel
        node = parent[node]
    path[0, 0], path[0, 1], path[0, 2] = pos[0], pos[1], pos[2]
    # first leg: farthest path voxel within leg_max_m along the path seen in a straight line
    leg = 0
    for k in range(1, _last_within(path, 0, 0.0, leg_max_m) + 1):
        if _line_of_sight(grid, origin, voxel, pos, path[k], lo, ny, nz, nx, trav, sx, sy, sz):
            leg = k
    return path, leg, reached, expanded


@numba.njit(cache=True, inline="always")
def _last_within(path, k0, along_m, leg_max_m):
    """The last row of ``path`` from ``k0`` whose length along the path (``along_m`` at row
    ``k0``, then summed row to row) is within ``leg_max_m``."""
    last = k0
    for k in range(k0 + 1, path.shape[0]):
        along_m += math.sqrt(
            (path[k, 0] - path[k - 1, 0]) ** 2
            + (path[k, 1] - path[k - 1, 1]) ** 2
            + (path[k, 2] - path[k - 1, 2]) ** 2
        )
        if along_m > leg_max_m + 1e-9:
            break
        last = k
    return last


@numba.njit(cache=True)
def _line_of_sight(grid, origin, voxel, pos, end, lo, ny, nz, nx, trav, sx, sy, sz):
    """Every half-voxel sample from ``pos`` to ``end`` lies in a voxel the search found
    traversable (or the vehicle's own voxel)."""
    dx, dy, dz = end[0] - pos[0], end[1] - pos[1], end[2] - pos[2]
    length = math.sqrt(dx * dx + dy * dy + dz * dz)
    steps = math.ceil(length / (0.5 * voxel))
    for s in range(1, steps + 1):
        t = s / steps
        gx = math.floor((pos[0] + t * dx) / voxel) - origin[0]
        gy = math.floor((pos[1] + t * dy) / voxel) - origin[1]
        gz = math.floor((pos[2] + t * dz) / voxel) - origin[2]
        if gx == sx and gy == sy and gz == sz:
            continue
        ix, iy, iz = gx - lo[0], gy - lo[1], gz - lo[2]
        if ix < 0 or iy < 0 or iz < 0 or ix >= nx or iy >= ny or iz >= nz:
            return False
        if trav[ix * ny * nz + iy * nz + iz] != 1:
            return False
    return True


@numba.njit(cache=True)
def _voxel_clear(grid, gx, gy, gz, centre, spheres, occ_off, sec_off, check_section):
    """The search's test of one voxel (traversable, and no OCCUPIED or TENTATIVE voxel
    within the clearance), asked of one voxel alone (the search stamps the clearance over
    its whole box once)."""
    if _traversable(grid, gx, gy, gz, centre, spheres, sec_off, check_section) != 1:
        return False
    for n in range(occ_off.shape[0]):
        s = _state(grid, gx + occ_off[n, 0], gy + occ_off[n, 1], gz + occ_off[n, 2])
        if s == OCCUPIED:
            return False
        if s == TENTATIVE:
            return False
    return True


@numba.njit(cache=True)
def _clear_line(grid, origin, voxel, pos, end, spheres, occ_off, sec_off, near_m):
    """Every half-voxel sample from ``pos`` to ``end`` lies in a clear voxel (or the
    vehicle's own): :func:`_line_of_sight` without the search's table."""
    sx = math.floor(pos[0] / voxel)
    sy = math.floor(pos[1] / voxel)
    sz = math.floor(pos[2] / voxel)
    dx, dy, dz = end[0] - pos[0], end[1] - pos[1], end[2] - pos[2]
    length = math.sqrt(dx * dx + dy * dy + dz * dz)
    steps = math.ceil(length / (0.5 * voxel))
    centre = np.empty(3)
    lx, ly, lz = sx, sy, sz
    for s in range(1, steps + 1):
        t = s / steps
        gx = math.floor((pos[0] + t * dx) / voxel)
        gy = math.floor((pos[1] + t * dy) / voxel)
        gz = math.floor((pos[2] + t * dz) / voxel)
        if (gx == sx and gy == sy and gz == sz) or (gx == lx and gy == ly and gz == lz):
            continue
        lx, ly, lz = gx, gy, gz
        centre[0] = (gx + 0.5) * voxel
        centre[1] = (gy + 0.5) * voxel
        centre[2] = (gz + 0.5) * voxel
        far = math.sqrt(
            (centre[0] - pos[0]) ** 2 + (centre[1] - pos[1]) ** 2 + (centre[2] - pos[2]) ** 2
        )
        ix, iy, iz = gx - origin[0], gy - origin[1], gz - origin[2]
        if not _voxel_clear(grid, ix, iy, iz, centre, spheres, occ_off, sec_off, far > near_m):
            return False
    return True


@numba.njit(cache=True)
def _follow(grid, origin, voxel, pos, path, spheres, occ_off, sec_off, near_m, leg_max_m, rejoin_m):
    """The rest of ``path`` (rows 1…) from its voxel nearest ``pos``: (first row kept, leg
    row), (-1, -1) when the vehicle is farther than ``rejoin_m`` from it or a voxel of the
    rest is no longer clear, leg -1 when no row within ``leg_max_m`` is seen in a line."""
    n = path.shape[0]
    k0 = -1
    best = np.inf
    for k in range(1, n):
        d = math.sqrt(
            (path[k, 0] - pos[0]) ** 2 + (path[k, 1] - pos[1]) ** 2 + (path[k, 2] - pos[2]) ** 2
        )
        if d < best:
            best, k0 = d, k
    if k0 < 0 or best > rejoin_m:
        return -1, -1
    sx = math.floor(pos[0] / voxel)
    sy = math.floor(pos[1] / voxel)
    sz = math.floor(pos[2] / voxel)
    for k in range(k0, n):
        gx = math.floor(path[k, 0] / voxel)
        gy = math.floor(path[k, 1] / voxel)
        gz = math.floor(path[k, 2] / voxel)
        if gx == sx and gy == sy and gz == sz:
            continue
        far = math.sqrt(
            (path[k, 0] - pos[0]) ** 2 + (path[k, 1] - pos[1]) ** 2 + (path[k, 2] - pos[2]) ** 2
        )
        ix, iy, iz = gx - origin[0], gy - origin[1], gz - origin[2]
        if not _voxel_clear(grid, ix, iy, iz, path[k], spheres, occ_off, sec_off, far > near_m):
            return -1, -1
    last = _last_within(path, k0, best, leg_max_m)
    for k in range(last, k0 - 1, -1):  # the farthest row seen in a straight line
        if _clear_line(grid, origin, voxel, pos, path[k], spheres, occ_off, sec_off, near_m):
            return k0, k
    return k0, -1


@numba.njit(cache=True)
def _body_meets_surface(grid, origin, voxel, a, b, body_off):
    """A half-voxel sample of the segment ``a → b`` has an OCCUPIED voxel among the
    offsets ``body_off`` about its voxel (a ball measured to the voxels' faces)."""
    dx, dy, dz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    length = math.sqrt(dx * dx + dy * dy + dz * dz)
    steps = max(math.ceil(length / (0.5 * voxel)), 1)
    lx, ly, lz = -(2**62), 0, 0
    for s in range(steps + 1):
        t = s / steps
        gx = math.floor((a[0] + t * dx) / voxel) - origin[0]
        gy = math.floor((a[1] + t * dy) / voxel) - origin[1]
        gz = math.floor((a[2] + t * dz) / voxel) - origin[2]
        if gx == lx and gy == ly and gz == lz:
            continue
        lx, ly, lz = gx, gy, gz
        for n in range(body_off.shape[0]):
            if (
                _state(grid, gx + body_off[n, 0], gy + body_off[n, 1], gz + body_off[n, 2])
                == OCCUPIED
            ):
                return True
    return False


def _sphere_array(spheres: Iterable) -> np.ndarray:
    rows = [
        (*(float(x) for x in s.center_ned_m), float(s.radius_m))
        for s in spheres  # anything with center_ned_m and radius_m
    ]
    return np.array(rows, dtype=float).reshape(-1, 4)


@functools.cache
def _offset_tables(cfg: KnownPathConfig, voxel_m: float) -> tuple[np.ndarray, np.ndarray]:
    occ = _offsets(cfg.clearance_m, cfg.clearance_m, voxel_m, face=True)
    sec = _offsets(cfg.section_radius_m, cfg.section_half_height_m, voxel_m, face=False)
    return occ, sec


def plan_known_path(
    grid: np.ndarray,
    origin_vox: np.ndarray,
    voxel_m: float,
    pos_ned_m,
    goal_ned_m,
    *,
    spheres: Iterable = (),
    config: KnownPathConfig | None = None,
) -> KnownPath | None:
    """Search the known-space map for a path from the vehicle toward the goal.

    Parameters
    ----------
    grid : ndarray of int8, shape (X, Y, Z)
        The map's voxel states (:attr:`companion.known_space.KnownSpace.grid`).
    origin_vox : ndarray of int64, shape (3,)
        Global voxel index of ``grid[0, 0, 0]`` (``KnownSpace.origin_vox``).
    voxel_m : float
        Voxel edge [m].
    pos_ned_m, goal_ned_m : array_like, shape (3,)
        Vehicle and goal [m, NED].
    spheres : iterable of sphere-likes (``center_ned_m``, ``radius_m``)
        Inflated boundaries the path must stay out of.
    config : KnownPathConfig, optional

    Returns
    -------
    KnownPath or None
        None when the vehicle cannot leave its own voxel through known-free space.
    """
    cfg = KnownPathConfig() if config is None else config
    pos = np.asarray(pos_ned_m, dtype=float).reshape(3)
    goal = np.asarray(goal_ned_m, dtype=float).reshape(3)
    if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(goal))):
        raise ValueError("pos_ned_m and goal_ned_m must be finite")
    occ, sec = _offset_tables(cfg, float(voxel_m))
    path, leg, reached, expanded = _search(
        grid, np.asarray(origin_vox, dtype=np.int64), float(voxel_m), pos, goal,
        math.ceil(cfg.reach_m / voxel_m), math.ceil(cfg.reach_z_m / voxel_m),
        _sphere_array(spheres), occ, sec, cfg.near_field_m, cfg.vertical_weight,
        cfg.max_expansions, cfg.leg_max_m, cfg.slack_m,
    )  # fmt: skip
    if path.shape[0] < 2 or leg == 0:
        return None
    steps = np.diff(path, axis=0)
    path.setflags(write=False)
    leg_end = path[leg].copy()
    leg_end.setflags(write=False)
    return KnownPath(
        waypoints_ned_m=path,
        leg_end_ned_m=leg_end,
        reaches_goal=bool(reached),
        end_to_goal_m=float(np.linalg.norm(path[-1] - goal)),
        length_m=float(np.sum(np.linalg.norm(steps, axis=1))),
        expanded=int(expanded),
    )
