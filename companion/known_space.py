"""Known space: a bounded, vehicle-centred voxel map of what the camera has seen free.

The safety envelope (DESIGN.md, "The safety envelope") needs to know, for a direction of
travel, how far the vehicle's body can move through space that was *seen* free. This
module keeps that knowledge; it is pure (no clock, no I/O) and fed once per depth frame
with the pose at the frame's capture time.

Model
-----
A grid of ``size_xy_vox × size_xy_vox × size_z_vox`` cubic voxels of ``voxel_m`` [m],
aligned with LOCAL_NED, each UNKNOWN (0), FREE (1), OCCUPIED (2) or TENTATIVE (3). The grid is
vehicle-centred: when the vehicle strays more than a quarter of the grid from its centre
the grid is shifted by whole voxels (what falls off the edge is forgotten, what enters is
UNKNOWN). Nothing is forgotten by a timer: OCCUPIED stays until a matched ray passes
through it.

Update, per depth frame (:meth:`KnownSpace.integrate`, a numba kernel casting one ray per
``pixel_stride`` × ``pixel_stride`` block, through the block's centre, to the *nearest*
matched depth in the block — min-pooling fills small matching holes conservatively and
does not miss a thin obstacle between rays — when at least ``block_min_matched`` of the
block is matched):

* **Matched, in range** (finite depth, range ≤ ``max_range_m``): voxels along the ray are
  FREE up to ``hit_clear_m`` short of the hit (also clearing OCCUPIED: seen free again);
  the hit's voxel becomes TENTATIVE (3) on its first frame and OCCUPIED when hit again in
  a later frame (a one-frame false match — a speckle, a mismatch — is not an obstacle; a
  real surface is hit in every frame). TENTATIVE is not free either. Within one frame a
  hit wins over free space (OctoMap's rule): the free segments are marked after all of
  the frame's hits and never clear them, so a ray that grazes a voxel on its way to a
  farther surface does not erase the surface another ray hit there. Without this an
  obstacle seen obliquely at close range — the flank the vehicle is passing — never
  became occupied: its limb voxels were hit and cleared again in every frame.
  A ray frees only the voxels whose centre it passes within a *core* radius:
  ``free_core_m`` for UNKNOWN ones, ``clear_core_m`` for OCCUPIED or TENTATIVE ones. A
  ray through a voxel's corner saw that corner free, not the rest of it: the rays that
  graze an obstacle's limb (in every frame, at the edge of the silhouette) otherwise
  freed voxels reaching 0.17 m into it, and the swept section's samples found free
  space inside the flank they were about to hit (Monte Carlo seed 762).
* **Range-aware occupancy** (issue 36): a hit is good to a pixel of disparity, so to a
  voxel only from ``√(voxel · f · b / confirm_disparity_px)`` (3.8 m with the paper's
  camera at 1 px; at 8 m one pixel is 0.89 m). ``near_hit`` records, per voxel, a hit
  from within that range since it was last FREE. A far hit still becomes OCCUPIED by the
  two-frame rule (the proximity sectors hear of a wall at their range, guidance avoids
  it), but while no near hit confirms it, it is not a surface *seen near*
  (:meth:`KnownSpace.seen_near`: what latches a goal as unreachable). Seeing a far-only
  voxel through with the wider core of unknown space was tried and dropped: it lost
  passages corridor-9 (a goal at the base, ``no_progress`` with it). Found
  on the suite's Monte Carlo seed 102: voxels 0.52–0.92 m in front of a sphere's true
  surface, hit from 7.7 m for 200+ frames, latched a ``goal_unreachable`` hold; a rule
  on the number of frames cannot drop a consistent bias. The far layer keeps the old
  rule.
* **Matched, beyond range** (finite or +inf depth, range > ``max_range_m``): FREE up to
  ``max_range_m``, nothing occupied.
* **Unmatched** (NaN depth: no match, the matcher's blind band, nearer than its minimum
  range, invalid): UNKNOWN, nothing written — with one exception, the *open sky*. An
  unmatched pixel whose column above it (to the top of the image) is unmatched too, which
  lies outside the matcher's blind band and whose ray points no lower than
  ``sky_min_elevation_deg`` below the horizon, is taken as open sky: FREE up to
  ``max_range_m`` and no farther out (horizontally) than the point of the column's
  topmost matched pixel, where still UNKNOWN or TENTATIVE (it never clears OCCUPIED). Without
  this a stereo camera could never certify the space at its own altitude (the sky above
  the horizon is textureless and never matches), and the vehicle could not fly level.
  The column rule keeps the exception away from textureless obstacles in front of the
  sky: their outline is matched at a finite depth, and every pixel below a matched pixel
  in its column stays UNKNOWN. The reach rule keeps it away from a textureless obstacle
  taller than the view: whatever stands in the unmatched part of a column stands on, or
  beyond, the last surface matched below it (the ground in front of a wall), so the sky
  is free only up to there, and a column with no matched pixel at all (the wall fills
  it) has no sky. Named limitation: a textureless obstacle hanging in front of far,
  matched ground, with no matched edge, is mistaken for sky.
  A TENTATIVE voxel (hit in one frame only) is seen free by open sky as by a matched ray:
  a sky ray through its core (``clear_core_m``) whose free segment reaches past its
  centre. Issue 36, facing_away-304: two voxels a one-frame false match made on the
  path's centre line, 0.5-0.8 m ahead at the camera's height, lay in open sky nearer than
  the matcher reaches; only sky rays crossed them, and the rule that freed only UNKNOWN
  kept them in the way for 40 s. What was hit in two frames (OCCUPIED) stays; the blind
  band is never sky, so a pole hit once and then in the band stays TENTATIVE; the reach
  rule stops the sky short of a textureless obstacle standing on matched ground.
* **The vehicle itself**: OCCUPIED voxels centred within ``ego_clear_radius_m`` of the
  vehicle become FREE (the vehicle is there). UNKNOWN is never made FREE around the
  vehicle: a bubble that moved with it would let it creep into unseen space, one bubble
  at a time. Only the first frame frees a ball of ``start_free_radius_m`` (named
  assumption: the vehicle starts in a clear bubble, as after a take-off; the camera
  cannot see beside or below itself).

Query (:meth:`KnownSpace.free_distance_m`): the distance the vehicle's body, an ellipse
normal to the direction (``radius_m`` wide, ``half_height_m`` high; its centre, 8
points on its rim and 8 on the ellipse of half its size, so that no voxel fits between
two samples), can travel from a position along a direction, in steps of half a voxel,
up to a limit: the centre must be in FREE voxels beyond ``body_m`` (inside it is the
vehicle), the other samples in FREE voxels beyond ``near_field_m`` and in voxels that
are not OCCUPIED (UNKNOWN or TENTATIVE) before it. The near field is where the rim is outside
any forward camera's view (0.35 m to the right is in the left eye's ±24° view only from
1.0 m ahead): what the vehicle could not have looked at without being there, excused
only when it was never seen occupied and lies outside every sphere where an obstacle may
be (``solid_ned_m``: the collision safety boundaries without their inflation, each a
piece of occupied space and its blind spot, Fig. 4 — the unseen flank of an obstacle
whose other side was seen is taken as obstacle). Named limitation: a thin obstacle that
reaches into the rim's path only within 1 m ahead, never into the view and never near
anything seen occupied. The envelope passes ``near_field_m`` only for a path the camera
looks along (:mod:`companion.guidance.envelope`, step 2): the flank of an obstacle
beside a path the vehicle has not looked along is not in the view either (windy seed
147). Outside the grid is UNKNOWN.

Costs (``benchmarks/bench_known_space.py``): median 0.9–1.1 ms per 320 × 240 frame at the
default stride of 4 (up to 4 800 rays) on the 2-core machine under a load of 8–9; with the
far layer (``far_range_m``, on by default) 1.44–1.51 ms against 1.02–1.11 ms without it
(thread CPU time, medians of 40 frames of the paper's approach, 5 repeats, load 18); the
budget is 2 ms.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numba
import numpy as np

from companion.known_space_config import KnownSpaceConfig
from protocols.camera import R_FRD_FROM_CAM, StereoIntrinsics, eye_offset_frd_m

__all__ = [
    "FREE",
    "OCCUPIED",
    "TENTATIVE",
    "UNKNOWN",
    "KnownSpace",
    "KnownSpaceConfig",
    "Pieces",
]

UNKNOWN = np.int8(0)
FREE = np.int8(1)
OCCUPIED = np.int8(2)
TENTATIVE = np.int8(3)  # hit in one frame only: not free, not yet an obstacle
_NEW_HIT = 4  # first hit, in the frame being integrated (becomes TENTATIVE at its end)
_NEW_HIT_AGAIN = 5  # hit in this frame and in an earlier one (becomes OCCUPIED at its end)


@dataclass(frozen=True, eq=False)
class Pieces:
    """OCCUPIED space cut into bounded pieces (:meth:`KnownSpace.pieces`), one row each.

    Attributes
    ----------
    key : ndarray, shape (n, 3), int64
        Global index of the piece's cube (``floor(point / (piece_vox · voxel_m))``): the
        same cube has the same key in every frame, wherever the grid is centred.
    centroid_ned_m : ndarray, shape (n, 3)
        Mean of the centres of its OCCUPIED voxels [m, NED].
    radius_m : ndarray, shape (n,)
        Radius of the sphere about the centroid that encloses its voxels (whole cubes) [m].
    n_voxels : ndarray, shape (n,), int64
    nearest_m : ndarray, shape (n,)
        Distance from the query position to its nearest voxel centre [m].
    nearest_to_point_m : ndarray, shape (n,)
        Distance from the query's second point (the goal) to its nearest voxel centre [m].
    """

    key: np.ndarray
    centroid_ned_m: np.ndarray
    radius_m: np.ndarray
    n_voxels: np.ndarray
    nearest_m: np.ndarray
    nearest_to_point_m: np.ndarray

    def __len__(self) -> int:
        return int(self.radius_m.shape[0])


# ---- kernels -----------------------------------------------------------------------------


@numba.njit(cache=True, inline="always")
def _cell(grid, origin, inv_voxel, x, y, z):
    """Grid indices of NED point (x, y, z), or (-1, 0, 0) outside the grid."""
    i = math.floor(x * inv_voxel) - origin[0]
    j = math.floor(y * inv_voxel) - origin[1]
    k = math.floor(z * inv_voxel) - origin[2]
    if i < 0 or j < 0 or k < 0 or i >= grid.shape[0] or j >= grid.shape[1] or k >= grid.shape[2]:
        return -1, 0, 0
    return i, j, k


@numba.njit(cache=True)
def _mark_ray(
    grid, near, origin, voxel, ox, oy, oz, dx, dy, dz, length, core_m, free_core_m, sky_core_m
):
    """FREE in every UNKNOWN voxel whose centre the segment from (ox, oy, oz) over
    ``length`` [m] passes within ``free_core_m`` [m] of, and in every OCCUPIED or
    TENTATIVE one whose centre it passes within ``core_m`` [m] of (0: never); an open-sky
    segment (``core_m`` 0) frees a TENTATIVE voxel whose centre lies on it, within
    ``sky_core_m`` [m] of it (0: never). A voxel made FREE forgets that it was hit from
    near (``near``).

    Amanatides–Woo traversal: each voxel is visited once, in order along the ray; the
    walk stops at the grid's edge. ``(dx, dy, dz)`` is a unit direction.
    """
    inv = 1.0 / voxel
    gx = ox * inv
    gy = oy * inv
    gz = oz * inv
    i = math.floor(gx) - origin[0]
    j = math.floor(gy) - origin[1]
    k = math.floor(gz) - origin[2]
    big = 1e30
    si = 1 if dx > 0.0 else -1
    sj = 1 if dy > 0.0 else -1
    sk = 1 if dz > 0.0 else -1
    # ray parameter [m] to the first boundary on each axis, and between boundaries
    if dx != 0.0:
        bx = math.floor(gx) + (1.0 if dx > 0.0 else 0.0)
        tx = (bx - gx) * voxel / dx
        ddx = voxel / abs(dx)
    else:
        tx = big
        ddx = big
    if dy != 0.0:
        by = math.floor(gy) + (1.0 if dy > 0.0 else 0.0)
        ty = (by - gy) * voxel / dy
        ddy = voxel / abs(dy)
    else:
        ty = big
        ddy = big
    if dz != 0.0:
        bz = math.floor(gz) + (1.0 if dz > 0.0 else 0.0)
        tz = (bz - gz) * voxel / dz
        ddz = voxel / abs(dz)
    else:
        tz = big
        ddz = big
    ni, nj, nk = grid.shape
    t = 0.0
    while True:
        if i < 0 or j < 0 or k < 0 or i >= ni or j >= nj or k >= nk:
            return
        cur = grid[i, j, k]
        sky_tentative = core_m == 0.0 and sky_core_m > 0.0 and cur == 3
        if cur == 0 or (core_m > 0.0 and (cur == 2 or cur == 3)) or sky_tentative:
            # only a ray through the voxel's core sees it free: one that crosses a corner
            # saw that corner free, not the rest of the voxel (the inside of an obstacle
            # whose limb it grazed; the surface point that made the voxel occupied). A
            # hit of the frame being integrated (4, 5) is never cleared.
            qx = (i + origin[0] + 0.5) * voxel - ox
            qy = (j + origin[1] + 0.5) * voxel - oy
            qz = (k + origin[2] + 0.5) * voxel - oz
            along = qx * dx + qy * dy + qz * dz
            off2 = qx * qx + qy * qy + qz * qz - along * along
            core = free_core_m if cur == 0 else (sky_core_m if sky_tentative else core_m)
            # open sky frees a voxel hit once only up to its reach, not past its end
            if off2 <= core * core and (not sky_tentative or along <= length):
                grid[i, j, k] = 1
                near[i, j, k] = 0
        if tx <= ty and tx <= tz:
            t = tx
            tx += ddx
            i += si
        elif ty <= tz:
            t = ty
            ty += ddy
            j += sj
        else:
            t = tz
            tz += ddz
            k += sk
        if t > length:
            return


@numba.njit(cache=True)
def _integrate_depth(
    grid,
    near,
    origin,
    voxel,
    depth,
    stride,
    min_matched,
    fx,
    fy,
    cx,
    cy,
    cam_ned,
    R_ned_from_cam,
    max_range,
    hit_clear,
    clear_core,
    free_core,
    sky_min_sin_elev,
    blind_band_px,
    near_m,
):
    """Cast one ray per ``stride`` × ``stride`` block of ``depth`` (float32, NaN unknown).

    ``near`` (uint8, the grid's shape) is set to 1 in every voxel hit from within
    ``near_m`` [m] (range-aware occupancy, :class:`KnownSpaceConfig`
    ``confirm_disparity_px``; ``inf``: every hit).

    A block with at least ``min_matched`` matched pixels casts a ray through its centre to
    the *nearest* of them (min-pooling: small holes are filled conservatively and a thin
    obstacle between block centres is not missed); a block wholly above the first matched
    pixel of each of its columns is open sky (see the module docstring); any other block
    is unknown. Returns the number of rays cast.
    """
    height, width = depth.shape
    inv = 1.0 / voxel
    n_rays = 0
    n_blocks = (width // stride) * (height // stride)
    new_hits = np.empty((n_blocks, 3), np.int64)
    n_new = 0
    segments = np.empty((n_blocks, 5))  # free segments: direction, length, core_m (0: sky)
    n_seg = 0
    # first matched row of every column (0 in the blind band: never sky) and the
    # horizontal distance of its point: how far the column's sky may be free
    first_matched = np.empty(width, np.int64)
    sky_reach = np.zeros(width)
    for u in range(width):
        first_matched[u] = height
        if u < blind_band_px:
            first_matched[u] = 0
            continue
        for v in range(height):
            d = depth[v, u]
            if not math.isnan(d):
                first_matched[u] = v
                if d > 0.0 and math.isinf(d):
                    sky_reach[u] = np.inf
                elif d > 0.0:
                    cx_m = d * (u - cx) / fx
                    cy_m = d * (v - cy) / fy
                    n_m = R_ned_from_cam[0, 0] * cx_m + R_ned_from_cam[0, 1] * cy_m
                    e_m = R_ned_from_cam[1, 0] * cx_m + R_ned_from_cam[1, 1] * cy_m
                    n_m += R_ned_from_cam[0, 2] * d
                    e_m += R_ned_from_cam[1, 2] * d
                    sky_reach[u] = math.sqrt(n_m * n_m + e_m * e_m)
                break
    for bu in range(0, width - stride + 1, stride):
        sky_rows = height
        reach = np.inf
        for u in range(bu, bu + stride):
            sky_rows = min(sky_rows, first_matched[u])
            reach = min(reach, sky_reach[u])
        xn = (bu + 0.5 * (stride - 1) - cx) / fx
        for bv in range(0, height - stride + 1, stride):
            n_matched = 0
            d = np.inf
            for v in range(bv, bv + stride):
                for u in range(bu, bu + stride):
                    dv = depth[v, u]
                    if not math.isnan(dv):
                        n_matched += 1
                        if dv < d:
                            d = dv
            yn = (bv + 0.5 * (stride - 1) - cy) / fy
            norm = math.sqrt(xn * xn + yn * yn + 1.0)
            # unit ray direction, camera frame then NED
            ux = xn / norm
            uy = yn / norm
            uz = 1.0 / norm
            dx = R_ned_from_cam[0, 0] * ux + R_ned_from_cam[0, 1] * uy + R_ned_from_cam[0, 2] * uz
            dy = R_ned_from_cam[1, 0] * ux + R_ned_from_cam[1, 1] * uy + R_ned_from_cam[1, 2] * uz
            dz = R_ned_from_cam[2, 0] * ux + R_ned_from_cam[2, 1] * uy + R_ned_from_cam[2, 2] * uz
            if n_matched < min_matched:
                # open sky: the whole block above its columns' first matched pixels, not
                # too far below the horizon (NED z down: elevation sine = -dz)
                if n_matched == 0 and bv + stride <= sky_rows and -dz >= sky_min_sin_elev:
                    # ... and no farther out than the column's topmost matched point (a
                    # textureless wall stands behind the last ground seen before it)
                    limit = reach - hit_clear  # > 0 before any division below
                    horizontal = math.sqrt(dx * dx + dy * dy)
                    length = max_range
                    if limit <= 0.0:
                        length = 0.0
                    elif horizontal * max_range > limit:
                        length = limit / horizontal
                    if length > 0.0:
                        segments[n_seg, 0] = dx
                        segments[n_seg, 1] = dy
                        segments[n_seg, 2] = dz
                        segments[n_seg, 3] = length
                        segments[n_seg, 4] = 0.0  # sky: never clears an obstacle
                        n_seg += 1
                        n_rays += 1
                continue
            if d <= 0.0:
                continue
            rng = d * norm  # depth along the optical axis → range along the ray
            n_rays += 1
            free_len = max_range if rng > max_range else rng - hit_clear
            if free_len > 0.0:
                segments[n_seg, 0] = dx
                segments[n_seg, 1] = dy
                segments[n_seg, 2] = dz
                segments[n_seg, 3] = free_len
                segments[n_seg, 4] = clear_core
                n_seg += 1
            if rng > max_range:
                continue
            i, j, k = _cell(
                grid, origin, inv, cam_ned[0] + rng * dx, cam_ned[1] + rng * dy,
                cam_ned[2] + rng * dz,
            )  # fmt: skip
            if i >= 0:
                if rng <= near_m:
                    near[i, j, k] = 1
                cur = grid[i, j, k]
                if cur < _NEW_HIT:
                    # hit in an earlier frame too (OCCUPIED, TENTATIVE): an obstacle
                    grid[i, j, k] = _NEW_HIT_AGAIN if cur == 2 or cur == 3 else _NEW_HIT
                    new_hits[n_new, 0] = i
                    new_hits[n_new, 1] = j
                    new_hits[n_new, 2] = k
                    n_new += 1
    # free space after every hit is known: within one frame a surface wins over the rays
    # that pass beside it (a ray grazing a voxel on its way to a farther surface must not
    # clear the voxel another ray hit, OctoMap's rule), so an obstacle seen obliquely —
    # its flank, passed at close range — still becomes occupied
    for s in range(n_seg):
        _mark_ray(grid, near, origin, voxel, cam_ned[0], cam_ned[1], cam_ned[2],
                  segments[s, 0], segments[s, 1], segments[s, 2], segments[s, 3],
                  segments[s, 4], free_core, clear_core)  # fmt: skip
    for h in range(n_new):  # this frame's hits: tentative on a first hit, else occupied
        i, j, k = new_hits[h, 0], new_hits[h, 1], new_hits[h, 2]
        if grid[i, j, k] == _NEW_HIT_AGAIN:
            grid[i, j, k] = 2
        elif grid[i, j, k] == _NEW_HIT:
            grid[i, j, k] = 3
    return n_rays


def _solid_array(solid_ned_m) -> np.ndarray:
    """``(n, 4)`` float64 rows ``(north, east, down, radius)`` [m], checked finite."""
    a = np.ascontiguousarray(solid_ned_m, dtype=float).reshape(-1, 4)
    if not np.all(np.isfinite(a)):
        raise ValueError("solid_ned_m must be finite")
    return a


@numba.njit(cache=True)
def _mark_ball(grid, near, origin, voxel, px, py, pz, radius, free_unknown, clear_occupied):
    """FREE for voxels centred within ``radius`` of (px, py, pz): UNKNOWN ones if
    ``free_unknown``, OCCUPIED or TENTATIVE ones if ``clear_occupied`` (which forget
    that they were hit from near)."""
    inv = 1.0 / voxel
    r_vox = math.ceil(radius * inv) + 1
    ci = math.floor(px * inv) - origin[0]
    cj = math.floor(py * inv) - origin[1]
    ck = math.floor(pz * inv) - origin[2]
    r2 = radius * radius
    for i in range(max(ci - r_vox, 0), min(ci + r_vox + 1, grid.shape[0])):
        xc = (i + origin[0] + 0.5) * voxel - px
        for j in range(max(cj - r_vox, 0), min(cj + r_vox + 1, grid.shape[1])):
            yc = (j + origin[1] + 0.5) * voxel - py
            for k in range(max(ck - r_vox, 0), min(ck + r_vox + 1, grid.shape[2])):
                zc = (k + origin[2] + 0.5) * voxel - pz
                if xc * xc + yc * yc + zc * zc <= r2:
                    cur = grid[i, j, k]
                    if (free_unknown and cur == 0) or (clear_occupied and cur >= 2):
                        grid[i, j, k] = 1
                        near[i, j, k] = 0


@numba.njit(cache=True)
def _free_distance(
    grid,
    origin,
    voxel,
    px,
    py,
    pz,
    ux,
    uy,
    uz,
    radius,
    half_height,
    limit,
    body,
    near_field,
    solid,
):
    """Largest s ≤ limit (half-voxel steps) with the body's section FREE from 0 to s.

    ``(ux, uy, uz)`` is a unit direction; the section is an ellipse normal to it with
    semi-axes ``radius`` (horizontal, ``e1 = u × down``) and ``half_height`` (``e2 = u ×
    e1``). Returns -1.0 when the section at s = 0 is not FREE.
    """
    inv = 1.0 / voxel
    # two unit vectors normal to u
    if abs(uz) < 0.9:
        ax, ay, az = 0.0, 0.0, 1.0
    else:
        ax, ay, az = 1.0, 0.0, 0.0
    e1x = uy * az - uz * ay
    e1y = uz * ax - ux * az
    e1z = ux * ay - uy * ax
    n1 = math.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
    e1x /= n1
    e1y /= n1
    e1z /= n1
    e2x = uy * e1z - uz * e1y
    e2y = uz * e1x - ux * e1z
    e2z = ux * e1y - uy * e1x
    # the centre, the rim and a ring half-way: samples at most a voxel apart across the
    # section (0.175 m at the 0.35 m radius), so no voxel lies unseen between two of them
    offs = np.zeros((17, 3))
    for m in range(16):
        a = (m % 8) * (math.pi / 4.0)
        scale = 1.0 if m < 8 else 0.5
        ca = math.cos(a) * radius * scale
        sa = math.sin(a) * half_height * scale
        offs[m + 1, 0] = ca * e1x + sa * e2x
        offs[m + 1, 1] = ca * e1y + sa * e2y
        offs[m + 1, 2] = ca * e1z + sa * e2z
    step = 0.5 * voxel
    n = int(limit / step)
    last = -1.0
    for s in range(n + 2):
        t = min(s * step, limit)
        for m in range(17):
            qx = px + t * ux + offs[m, 0]
            qy = py + t * uy + offs[m, 1]
            qz = pz + t * uz + offs[m, 2]
            i, j, k = _cell(grid, origin, inv, qx, qy, qz)
            if i < 0:
                return last
            cur = grid[i, j, k]
            if cur == 1:
                continue
            if m == 0 and t <= body:
                continue
            if m > 0 and t < near_field and (cur == 0 or cur == 3):
                # unseen near field, excused unless it may be inside an obstacle
                inside = False
                for b in range(solid.shape[0]):
                    sx = qx - solid[b, 0]
                    sy = qy - solid[b, 1]
                    sz = qz - solid[b, 2]
                    if sx * sx + sy * sy + sz * sz <= solid[b, 3] * solid[b, 3]:
                        inside = True
                        break
                if not inside:
                    continue
            return last
        last = t
        if t >= limit:
            break
    return last


@numba.njit(cache=True)
def _pieces(grid, origin, piece, voxel, px, py, pz, reach, qx, qy, qz):
    """OCCUPIED voxels cut into cubes of ``piece`` voxels (global, grid-aligned).

    A cube is a piece when one of its OCCUPIED voxels is centred within ``reach`` [m] of
    ``p``; all of its OCCUPIED voxels (in the grid) belong to it. Returns, per piece: the
    cube's global index (3 int64), the centroid of its voxel centres [m, NED], the radius
    of the sphere about the centroid enclosing its voxels (whole cubes) [m], the number of
    voxels and the distances from ``p`` and from ``q`` to the nearest voxel centre [m].
    """
    ni, nj, nk = grid.shape
    r_vox = math.ceil(reach / voxel) + 1
    ci = math.floor(px / voxel) - origin[0]
    cj = math.floor(py / voxel) - origin[1]
    ck = math.floor(pz / voxel) - origin[2]
    lo = np.array([max(ci - r_vox, 0), max(cj - r_vox, 0), max(ck - r_vox, 0)])
    hi = np.array([min(ci + r_vox + 1, ni), min(cj + r_vox + 1, nj), min(ck + r_vox + 1, nk)])
    if lo[0] >= hi[0] or lo[1] >= hi[1] or lo[2] >= hi[2]:
        none = np.zeros(0)
        return np.zeros((0, 3), np.int64), np.zeros((0, 3)), none, np.zeros(0, np.int64), none, none
    c_lo = np.empty(3, np.int64)
    n_c = np.empty(3, np.int64)
    for a in range(3):
        c_lo[a] = (lo[a] + origin[a]) // piece
        n_c[a] = (hi[a] - 1 + origin[a]) // piece - c_lo[a] + 1
    flag = np.zeros((n_c[0], n_c[1], n_c[2]), np.bool_)
    r2 = reach * reach
    for i in range(lo[0], hi[0]):
        x = (i + origin[0] + 0.5) * voxel - px
        for j in range(lo[1], hi[1]):
            y = (j + origin[1] + 0.5) * voxel - py
            for k in range(lo[2], hi[2]):
                if grid[i, j, k] != 2:
                    continue
                z = (k + origin[2] + 0.5) * voxel - pz
                if x * x + y * y + z * z <= r2:
                    flag[
                        (i + origin[0]) // piece - c_lo[0],
                        (j + origin[1]) // piece - c_lo[1],
                        (k + origin[2]) // piece - c_lo[2],
                    ] = True
    n = 0
    for a in range(n_c[0]):
        for b in range(n_c[1]):
            for c in range(n_c[2]):
                if flag[a, b, c]:
                    n += 1
    keys = np.empty((n, 3), np.int64)
    centroid = np.zeros((n, 3))
    radius = np.zeros(n)
    count = np.zeros(n, np.int64)
    near_p = np.full(n, np.inf)
    near_q = np.full(n, np.inf)
    m = 0
    half_diag = 0.5 * math.sqrt(3.0) * voxel
    for a in range(n_c[0]):
        for b in range(n_c[1]):
            for c in range(n_c[2]):
                if not flag[a, b, c]:
                    continue
                g = (c_lo[0] + a, c_lo[1] + b, c_lo[2] + c)
                keys[m, 0] = g[0]
                keys[m, 1] = g[1]
                keys[m, 2] = g[2]
                i0 = max(g[0] * piece - origin[0], 0)
                i1 = min((g[0] + 1) * piece - origin[0], ni)
                j0 = max(g[1] * piece - origin[1], 0)
                j1 = min((g[1] + 1) * piece - origin[1], nj)
                k0 = max(g[2] * piece - origin[2], 0)
                k1 = min((g[2] + 1) * piece - origin[2], nk)
                sx = sy = sz = 0.0
                for i in range(i0, i1):
                    x = (i + origin[0] + 0.5) * voxel
                    for j in range(j0, j1):
                        y = (j + origin[1] + 0.5) * voxel
                        for k in range(k0, k1):
                            if grid[i, j, k] != 2:
                                continue
                            z = (k + origin[2] + 0.5) * voxel
                            count[m] += 1
                            sx += x
                            sy += y
                            sz += z
                            dp = math.sqrt((x - px) ** 2 + (y - py) ** 2 + (z - pz) ** 2)
                            dq = math.sqrt((x - qx) ** 2 + (y - qy) ** 2 + (z - qz) ** 2)
                            near_p[m] = min(near_p[m], dp)
                            near_q[m] = min(near_q[m], dq)
                mx = sx / count[m]
                my = sy / count[m]
                mz = sz / count[m]
                centroid[m, 0] = mx
                centroid[m, 1] = my
                centroid[m, 2] = mz
                far2 = 0.0
                for i in range(i0, i1):
                    x = (i + origin[0] + 0.5) * voxel - mx
                    for j in range(j0, j1):
                        y = (j + origin[1] + 0.5) * voxel - my
                        for k in range(k0, k1):
                            if grid[i, j, k] == 2:
                                z = (k + origin[2] + 0.5) * voxel - mz
                                far2 = max(far2, x * x + y * y + z * z)
                radius[m] = math.sqrt(far2) + half_diag
                m += 1
    return keys, centroid, radius, count, near_p, near_q


@numba.njit(cache=True)
def _unseen_run(grid, origin, voxel, px, py, pz, ux, uy, uz, limit):
    """Distance [m] from p along the unit direction u to the first FREE voxel (≤ limit)."""
    inv = 1.0 / voxel
    step = 0.5 * voxel
    n = int(limit / step)
    for s in range(1, n + 1):
        t = s * step
        i, j, k = _cell(grid, origin, inv, px + t * ux, py + t * uy, pz + t * uz)
        if i >= 0 and grid[i, j, k] == 1:
            return t
    return limit


@numba.njit(cache=True)
def _unseen_runs(grid, origin, voxel, points, vx, vy, vz, limit):
    """:func:`_unseen_run` from each of ``points`` (n, 3) away from the viewpoint v."""
    out = np.zeros(points.shape[0])
    for m in range(points.shape[0]):
        dx = points[m, 0] - vx
        dy = points[m, 1] - vy
        dz = points[m, 2] - vz
        d = math.sqrt(dx * dx + dy * dy + dz * dz)
        if d > 1e-9:
            out[m] = _unseen_run(
                grid, origin, voxel, points[m, 0], points[m, 1], points[m, 2],
                dx / d, dy / d, dz / d, limit,
            )  # fmt: skip
    return out


@numba.njit(cache=True)
def _seen_near(grid, near, origin, voxel, px, py, pz, radius):
    """Whether an OCCUPIED voxel hit from near (``near`` 1) is centred within ``radius``
    [m] of (px, py, pz)."""
    inv = 1.0 / voxel
    r_vox = math.ceil(radius * inv) + 1
    ci = math.floor(px * inv) - origin[0]
    cj = math.floor(py * inv) - origin[1]
    ck = math.floor(pz * inv) - origin[2]
    r2 = radius * radius
    for i in range(max(ci - r_vox, 0), min(ci + r_vox + 1, grid.shape[0])):
        xc = (i + origin[0] + 0.5) * voxel - px
        for j in range(max(cj - r_vox, 0), min(cj + r_vox + 1, grid.shape[1])):
            yc = (j + origin[1] + 0.5) * voxel - py
            for k in range(max(ck - r_vox, 0), min(ck + r_vox + 1, grid.shape[2])):
                zc = (k + origin[2] + 0.5) * voxel - pz
                if grid[i, j, k] == 2 and near[i, j, k] == 1 and xc * xc + yc * yc + zc * zc <= r2:
                    return True
    return False


@functools.cache
def _warm_up() -> None:
    """Compile (or load from numba's cache) the kernels once per process."""
    grid = np.zeros((8, 8, 8), np.int8)
    near = np.zeros((8, 8, 8), np.uint8)
    origin = np.zeros(3, np.int64)
    depth = np.full((4, 4), np.nan, np.float32)
    depth[2, 2] = 0.5
    depth.flags.writeable = False  # perception's depth is read-only: its own specialization
    _integrate_depth(
        grid, near, origin, 0.2, depth, 2, 1, 2.0, 2.0, 1.5, 1.5, np.full(3, 0.8),
        np.eye(3), 1.0, 0.1, 0.05, 0.1, -0.1, 0, 1.0,
    )  # fmt: skip
    _mark_ball(grid, near, origin, 0.2, 0.8, 0.8, 0.8, 0.3, True, True)
    _seen_near(grid, near, origin, 0.2, 0.8, 0.8, 0.8, 0.5)
    _free_distance(
        grid, origin, 0.2, 0.8, 0.8, 0.8, 1.0, 0.0, 0.0, 0.1, 0.1, 0.5, 0.1, 0.2, np.zeros((1, 4))
    )
    grid[4, 4, 4] = OCCUPIED
    _pieces(grid, origin, 2, 0.2, 0.8, 0.8, 0.8, 0.5, 0.8, 0.8, 0.8)
    _unseen_runs(grid, origin, 0.2, np.full((1, 3), 0.8), 0.0, 0.0, 0.0, 0.5)


class KnownSpace:
    """The known-space map (see the module docstring); one per vehicle.

    Parameters
    ----------
    config : KnownSpaceConfig, optional
    """

    def __init__(self, config: KnownSpaceConfig | None = None) -> None:
        self.config = KnownSpaceConfig() if config is None else config
        c = self.config
        self.grid = np.zeros((c.size_xy_vox, c.size_xy_vox, c.size_z_vox), np.int8)
        # 1 where the voxel was hit from near since it was last FREE (range-aware
        # occupancy, KnownSpaceConfig.confirm_disparity_px)
        self.near_hit = np.zeros(self.grid.shape, np.uint8)
        self.origin_vox = np.zeros(3, np.int64)  # global voxel index of grid[0, 0, 0]
        self._started = False
        self.frames = 0
        self.range_m = float(c.max_range_m)  # how far the last frame's rays could free [m]
        far = c.far_config()
        # the far layer (KnownSpaceConfig.far_range_m): read by the proximity sectors only
        self.far: KnownSpace | None = None if far is None else KnownSpace(far)
        _warm_up()

    # -- frame of the grid -----------------------------------------------------------------

    def _centre_on(self, pos_ned_m: np.ndarray) -> None:
        """Shift the grid (whole voxels) so ``pos_ned_m`` is near its centre."""
        c = self.config
        shape = np.array(self.grid.shape, np.int64)
        vox = np.floor(np.asarray(pos_ned_m) / c.voxel_m).astype(np.int64)
        centre = self.origin_vox + shape // 2
        if self._started and np.all(np.abs(vox - centre) <= shape // 4):
            return
        new_origin = vox - shape // 2
        shift = new_origin - self.origin_vox
        new = np.zeros_like(self.grid)
        new_near = np.zeros_like(self.near_hit)
        if self._started:
            src = tuple(slice(max(s, 0), min(n + s, n)) for s, n in zip(shift, shape, strict=True))
            dst = tuple(slice(max(-s, 0), min(n - s, n)) for s, n in zip(shift, shape, strict=True))
            if all(sl.stop > sl.start for sl in src):
                new[dst] = self.grid[src]
                new_near[dst] = self.near_hit[src]
        self.grid = new
        self.near_hit = new_near
        self.origin_vox = new_origin

    # -- update ----------------------------------------------------------------------------

    def integrate(
        self,
        depth_m: np.ndarray,
        intrinsics: StereoIntrinsics,
        pos_ned_m,
        R_ned_from_frd,
        blind_band_px: int = 0,
        trusted_range_m: float = math.inf,
    ) -> int:
        """Fold one depth frame (left camera, NaN = unknown) in; returns the rays cast.

        Parameters
        ----------
        depth_m : ndarray, shape (H, W), float32
            Depth along the left camera's optical axis [m]; NaN unknown, +inf far.
        intrinsics : StereoIntrinsics
            The frame's camera (left eye at body ``y = -b/2``, looking along body +x).
        pos_ned_m : array_like, shape (3,)
            Vehicle position at the frame's capture time [m, NED].
        R_ned_from_frd : array_like, shape (3, 3)
            Body FRD → NED at the capture time.
        blind_band_px : int
            Left image columns the matcher cannot match (perception's
            ``blind_band_px``): never open sky.
        trusted_range_m : float
            How far the depth source vouches for a +inf pixel (perception's
            ``trusted_range_m``) [m]: rays, open sky included, free no farther than the
            smaller of it and ``max_range_m`` (:attr:`range_m` keeps it for the sectors).
        """
        c = self.config
        pos = np.asarray(pos_ned_m, dtype=float)
        R = np.asarray(R_ned_from_frd, dtype=float)
        self._centre_on(pos)
        self.range_m = float(min(c.max_range_m, trusted_range_m))
        if not self._started:
            _mark_ball(
                self.grid, self.near_hit, self.origin_vox, c.voxel_m, *pos,
                c.start_free_radius_m, True, False,
            )  # fmt: skip
            self._started = True
        cam_ned = pos + R @ eye_offset_frd_m(intrinsics.baseline_m, "left")
        R_ned_from_cam = np.ascontiguousarray(R @ R_FRD_FROM_CAM)
        depth = np.ascontiguousarray(depth_m, dtype=np.float32)
        n = _integrate_depth(
            self.grid,
            self.near_hit,
            self.origin_vox,
            c.voxel_m,
            depth,
            c.pixel_stride,
            max(1, math.ceil(c.block_min_matched * c.pixel_stride**2)),
            float(intrinsics.fx_px),
            float(intrinsics.fy_px),
            float(intrinsics.cx_px),
            float(intrinsics.cy_px),
            cam_ned,
            R_ned_from_cam,
            self.range_m,
            c.hit_clear_m,
            c.clear_core_m,
            c.free_core_m,
            math.sin(math.radians(c.sky_min_elevation_deg)),
            int(blind_band_px),
            self.near_range_m(intrinsics),
        )
        self.mark_vehicle(pos)
        self.frames += 1
        if self.far is not None:
            self.far.integrate(depth_m, intrinsics, pos, R, blind_band_px, trusted_range_m)
        return int(n)

    def mark_vehicle(self, pos_ned_m) -> None:
        """The vehicle is at ``pos_ned_m``: its surroundings are free (see module docstring)."""
        c = self.config
        pos = np.asarray(pos_ned_m, dtype=float)
        self._centre_on(pos)
        self._started = True
        _mark_ball(
            self.grid, self.near_hit, self.origin_vox, c.voxel_m, *pos, c.ego_clear_radius_m,
            False, True,
        )  # fmt: skip
        if self.far is not None:
            self.far.mark_vehicle(pos)

    def near_range_m(self, intrinsics: StereoIntrinsics) -> float:
        """Range [m] within which a hit of this camera is good to a voxel (range-aware
        occupancy): ``√(voxel · f · b / confirm_disparity_px)``; ``inf`` when the rule is
        off (``confirm_disparity_px`` 0) or the camera states no baseline."""
        c = self.config
        fb = float(intrinsics.fx_px) * float(intrinsics.baseline_m)
        if c.confirm_disparity_px <= 0.0 or not fb > 0.0:
            return math.inf
        return math.sqrt(c.voxel_m * fb / c.confirm_disparity_px)

    # -- queries ---------------------------------------------------------------------------

    def seen_near(self, point_ned_m, radius_m: float) -> bool:
        """Whether an OCCUPIED voxel centred within ``radius_m`` of ``point_ned_m`` was hit
        from near (:meth:`near_range_m`): a surface whose place the camera measured to a
        voxel, not one seen only from where a pixel of disparity is more than that."""
        p = np.asarray(point_ned_m, dtype=float)
        return bool(
            _seen_near(
                self.grid, self.near_hit, self.origin_vox, self.config.voxel_m, float(p[0]),
                float(p[1]), float(p[2]), float(radius_m),
            )
        )  # fmt: skip

    def state_at(self, point_ned_m) -> int:
        """UNKNOWN, FREE or OCCUPIED at a NED point (UNKNOWN outside the grid)."""
        c = self.config
        idx = np.floor(np.asarray(point_ned_m, dtype=float) / c.voxel_m).astype(np.int64)
        idx -= self.origin_vox
        if np.any(idx < 0) or np.any(idx >= np.array(self.grid.shape)):
            return int(UNKNOWN)
        return int(self.grid[tuple(idx)])

    def free_distance_m(
        self,
        pos_ned_m,
        direction_ned,
        radius_m: float,
        limit_m: float,
        half_height_m: float | None = None,
        body_m: float = 0.0,
        near_field_m: float = 0.0,
        solid_ned_m=None,
    ) -> float:
        """Known-free distance [m] for the vehicle's section moving along ``direction_ned``.

        The section is an ellipse normal to the direction, ``radius_m`` wide on each side
        (horizontal) and ``half_height_m`` (default ``radius_m``) high. Returns the largest
        distance ≤ ``limit_m`` (multiples of half a voxel) over which its centre and 16
        points on the rim and half-way to it stay in FREE voxels (the centre within
        ``body_m`` and the others within ``near_field_m``, except inside the spheres
        ``solid_ned_m``, rows ``(north, east, down, radius)`` [m]: see the module
        docstring); 0 when the vehicle cannot move at all (also for a zero direction).
        """
        u = np.asarray(direction_ned, dtype=float)
        n = math.sqrt(float(u @ u))
        if not n > 1e-9 or limit_m <= 0.0:
            return 0.0
        u = u / n
        p = np.asarray(pos_ned_m, dtype=float)
        d = _free_distance(
            self.grid,
            self.origin_vox,
            self.config.voxel_m,
            float(p[0]),
            float(p[1]),
            float(p[2]),
            float(u[0]),
            float(u[1]),
            float(u[2]),
            float(radius_m),
            float(radius_m if half_height_m is None else half_height_m),
            float(limit_m),
            float(body_m),
            float(near_field_m),
            _solid_array(() if solid_ned_m is None else solid_ned_m),
        )
        return max(float(d), 0.0)

    def pieces(
        self, pos_ned_m, reach_m: float, point_ned_m=None, piece_vox: int | None = None
    ) -> Pieces:
        """OCCUPIED space near ``pos_ned_m`` cut into pieces of bounded size.

        The grid is cut into cubes of ``piece_vox`` voxels aligned with LOCAL_NED; every
        cube holding an OCCUPIED voxel centred within ``reach_m`` of ``pos_ned_m`` is a
        piece, with all its OCCUPIED voxels. A piece's voxels lie within
        ``piece_vox · voxel_m · √3 / 2`` of its centroid (1.04 m by default), so an
        extended obstacle (a wall) is several pieces, never one growing blob; a small
        obstacle across cube faces is a few small pieces whose spheres overlap.
        ``point_ned_m`` (default ``pos_ned_m``): a second point whose distance to each
        piece's nearest voxel is reported (the goal's clearance to the real surface).
        ``piece_vox`` (default the config's) sets another cube edge [voxels].
        """
        c = self.config
        size = c.piece_vox if piece_vox is None else int(piece_vox)
        if size < 1:
            raise ValueError(f"piece_vox must be >= 1, got {piece_vox!r}")
        p = np.asarray(pos_ned_m, dtype=float)
        q = p if point_ned_m is None else np.asarray(point_ned_m, dtype=float)
        keys, centroid, radius, count, near_p, near_q = _pieces(
            self.grid,
            self.origin_vox,
            size,
            c.voxel_m,
            float(p[0]),
            float(p[1]),
            float(p[2]),
            float(reach_m),
            float(q[0]),
            float(q[1]),
            float(q[2]),
        )
        return Pieces(keys, centroid, radius, count, near_p, near_q)

    def unseen_run_m(self, start_ned_m, direction_ned, limit_m: float) -> float:
        """Distance [m] from ``start_ned_m`` along ``direction_ned`` to the first FREE
        voxel, in half-voxel steps, at most ``limit_m`` (outside the grid is unknown)."""
        u = np.asarray(direction_ned, dtype=float)
        n = math.sqrt(float(u @ u))
        if not n > 1e-9 or limit_m <= 0.0:
            return 0.0
        u = u / n
        p = np.asarray(start_ned_m, dtype=float)
        return float(
            _unseen_run(
                self.grid, self.origin_vox, self.config.voxel_m, float(p[0]), float(p[1]),
                float(p[2]), float(u[0]), float(u[1]), float(u[2]), float(limit_m),
            )
        )  # fmt: skip

    def unseen_runs_m(self, points_ned_m, viewpoint_ned_m, limit_m: float) -> np.ndarray:
        """:meth:`unseen_run_m` from each of ``points_ned_m`` (n, 3) along the direction
        away from ``viewpoint_ned_m`` (0 for a point at the viewpoint)."""
        pts = np.ascontiguousarray(points_ned_m, dtype=float).reshape(-1, 3)
        v = np.asarray(viewpoint_ned_m, dtype=float)
        if limit_m <= 0.0:
            return np.zeros(pts.shape[0])
        return _unseen_runs(
            self.grid, self.origin_vox, self.config.voxel_m, pts, float(v[0]), float(v[1]),
            float(v[2]), float(limit_m),
        )  # fmt: skip

    def occupied_points_ned_m(self) -> np.ndarray:
        """Centres of the OCCUPIED voxels [m, NED], shape (n, 3)."""
        idx = np.argwhere(self.grid == OCCUPIED)
        return (idx + self.origin_vox + 0.5) * self.config.voxel_m
