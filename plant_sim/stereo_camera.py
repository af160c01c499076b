"""Synthetic rectified stereo camera: ray-cast spheres, boxes, cylinders, ground, sky (numba).

The camera model and frames are :mod:`protocols.camera`'s: optical frame x right, y down,
z forward; the camera looks along body +x; left eye (reference) at body ``y = -b/2``, right
eye at ``y = +b/2``. Each pixel's ray is ``d = R_ned_from_cam · ((u − cx)/fx, (v − cy)/fy, 1)``,
so the ray parameter ``t`` of a hit *is* its depth along the optical axis.

Textures are procedural value noise fixed to the surfaces (a sphere's texture is a function of
the hit point relative to its centre, the ground's of its north/east coordinates), so both eyes
see the same texture and block matching locks on. Octaves finer than a pixel's footprint are
faded out (a cheap level of detail) so distant surfaces do not alias into eye-dependent noise.
The sky is a smooth gradient with faint clouds that depend only on the ray direction (they sit
at infinity: disparity 0). Sensor noise is a per-pixel integer hash of (seed, eye, u, v):
deterministic, no random-number-generator state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from plant_sim.world import World
from protocols.camera import R_FRD_FROM_CAM, CameraModel
from protocols.config import Checked, bounded

__all__ = ["RenderParams", "StereoCameraRenderer", "StereoRender"]

_LATTICE_SIZE = 32  # cells per lattice axis (power of two: indices wrap with & (L - 1))
_LATTICE_MASK = _LATTICE_SIZE - 1  # a compile-time constant: masked indices are provably >= 0


@dataclass(frozen=True)
class RenderParams(Checked):
    """Appearance and noise of the synthetic camera.

    Attributes
    ----------
    texture_cell_m : float
        Cell size of the finest obstacle texture octave [m]; the other octaves are
        3.3× and 11× coarser.
    ground_cell_m : float
        Cell size of the finest ground texture octave [m].
    noise_std : float
        Standard deviation of the additive sensor noise [grey levels]; 0 disables it.
    sky_cloud_amplitude : float
        Peak-to-peak contrast of the sky's clouds [grey levels].
    lattice_seed : int
        Seed of the value-noise lattice (the world's look).
    gain_right : float
        Right sensor's gain relative to the left (exposure/gain mismatch; 1 = matched).
    misrect_v_px : float
        Vertical misrectification [px]: the right image is shifted this much down (bilinear,
        border replicated); 0 = perfectly rectified.
    blur_h_px, blur_v_px : float
        Length of a horizontal / vertical motion blur [px] (a normalised line kernel of both
        images, applied before the sensor noise); 0 = sharp.
    jpeg_quality : int
        JPEG-compress both images at this quality (1-100) after the noise, as a compressed
        video link would; 0 = uncompressed.
    """

    texture_cell_m: float = bounded(0.03, "m", gt=0)
    ground_cell_m: float = bounded(0.05, "m", gt=0)
    noise_std: float = bounded(2.0, "grey level", ge=0)
    sky_cloud_amplitude: float = bounded(12.0, "grey level", ge=0)
    lattice_seed: int = bounded(12345, integer=True)
    gain_right: float = bounded(1.0, gt=0)
    misrect_v_px: float = bounded(0.0, "px")
    blur_h_px: float = bounded(0.0, "px", ge=0)
    blur_v_px: float = bounded(0.0, "px", ge=0)
    jpeg_quality: int = bounded(0, integer=True, ge=0, le=100)  # 0: uncompressed

    @property
    def degraded(self) -> bool:
        """Whether any image degradation beyond the sensor noise is set."""
        return (
            self.gain_right != 1.0
            or self.misrect_v_px != 0.0
            or self.blur_h_px > 0.0
            or self.blur_v_px > 0.0
            or self.jpeg_quality > 0
        )


@dataclass(frozen=True, eq=False)
class StereoRender:
    """One rendered stereo pair.

    Attributes
    ----------
    left, right : numpy.ndarray
        ``(H, W)`` uint8 rectified grayscale images; ``left`` is the reference.
    depth_left_m : numpy.ndarray
        ``(H, W)`` float32 true depth of the left image along the optical axis [m];
        ``inf`` for sky.
    """

    left: np.ndarray
    right: np.ndarray
    depth_left_m: np.ndarray


@numba.njit(cache=True, inline="always")
def _lod_weight(footprint_m, cell_m):
    """1 while a texture cell spans ≥ 4 pixels, fading to 0 at 1.5 pixels per cell."""
    ratio = footprint_m / cell_m
    if ratio <= 0.25:
        return 1.0
    if ratio >= 0.6667:
        return 0.0
    return (0.6667 - ratio) / (0.6667 - 0.25)


@numba.njit(cache=True, inline="always")
def _value_noise2(lat, x, y, layer):
    """Bilinear value noise on one lattice layer (cheaper 2-D variant for the ground).

    ``lat`` is the ``(L, L, L)`` lattice flattened (C order), indexed ``[ix, iy, layer]``.
    """
    mask = _LATTICE_MASK
    n = _LATTICE_SIZE
    fx0 = math.floor(x)
    fy0 = math.floor(y)
    tx = x - fx0
    ty = y - fy0
    tx = tx * tx * (3.0 - 2.0 * tx)
    ty = ty * ty * (3.0 - 2.0 * ty)
    ix = int(fx0) & mask
    iy = int(fy0) & mask
    jx = (ix + 1) & mask
    jy = (iy + 1) & mask
    layer &= mask
    a = lat[(ix * n + iy) * n + layer]
    b = lat[(jx * n + iy) * n + layer]
    c = lat[(ix * n + jy) * n + layer]
    d = lat[(jx * n + jy) * n + layer]
    c0 = a + (b - a) * tx
    c1 = c + (d - c) * tx
    return c0 + (c1 - c0) * ty


@numba.njit(cache=True, inline="always")
def _cube_face(x, y, z):
    """Cube mapping of a direction: (face 0..5, s, t) with s, t the two minor coordinates."""
    ax = abs(x)
    ay = abs(y)
    az = abs(z)
    if ax >= ay and ax >= az:
        return (0 if x > 0.0 else 1), y, z
    if ay >= az:
        return (2 if y > 0.0 else 3), z, x
    return (4 if z > 0.0 else 5), x, y


@numba.njit(cache=True, inline="always")
def _sphere_texture(lat, x, y, z, cell_m, footprint_m, seed_offset):
    """Two octaves (cell, 4× cell) of value noise on the sphere, cube-mapped, in [0, 1].

    ``(x, y, z)`` is the surface point relative to the centre; each of the six cube faces
    reads its own lattice layer, so the texture is fixed to the sphere and seamless enough
    for matching (both eyes see the same seams). Octaves finer than the pixel footprint fade.
    """
    face, s, t = _cube_face(x, y, z)
    layer = (int(seed_offset) + 5 * face) & _LATTICE_MASK
    return _two_octaves(lat, s, t, layer, 3, cell_m, footprint_m)


@numba.njit(cache=True, inline="always")
def _ground_texture(lat, x, y, cell_m, footprint_m, seed_offset):
    """Two octaves (cell and 4× cell) of 2-D value noise in [0, 1], level-of-detail faded."""
    return _two_octaves(lat, x, y, int(seed_offset) & _LATTICE_MASK, 7, cell_m, footprint_m)


@numba.njit(cache=True, inline="always")
def _two_octaves(lat, u, v, layer, coarse_shift, cell_m, footprint_m):
    """Value noise at the cell (layer ``layer``) and at 4× the cell (axes swapped, layer
    ``layer + coarse_shift``), each faded toward grey as the pixel footprint outgrows it."""
    fine = 0.5
    w = _lod_weight(footprint_m, cell_m)
    if w > 0.0:
        c = 1.0 / cell_m
        fine = 0.5 + w * (_value_noise2(lat, u * c, v * c, layer) - 0.5)
    coarse = 0.5
    w = _lod_weight(footprint_m, 4.0 * cell_m)
    if w > 0.0:
        c = 0.25 / cell_m
        coarse = 0.5 + w * (
            _value_noise2(lat, v * c, u * c, (layer + coarse_shift) & _LATTICE_MASK) - 0.5
        )
    return 0.55 * fine + 0.45 * coarse


@numba.njit(cache=True, inline="always")
def _trace(eye_sph, e, n_spheres, dx, dy, dz, aa):
    """Nearest sphere hit of one eye's ray: (t, k), ``(inf, -2)`` if none."""
    t_best = np.inf
    hit = -2  # -2 sky, -1 ground, k >= 0 sphere k
    for k in range(n_spheres):
        ox = eye_sph[e, k, 0]
        oy = eye_sph[e, k, 1]
        oz = eye_sph[e, k, 2]
        bb = ox * dx + oy * dy + oz * dz
        disc = bb * bb - aa * eye_sph[e, k, 3]
        if disc >= 0.0:
            sq = math.sqrt(disc)
            t = (-bb - sq) / aa
            if t <= 1e-6:
                t = (-bb + sq) / aa  # camera inside the sphere: its far wall
            if 1e-6 < t < t_best:
                t_best = t
                hit = k
    return t_best, hit


@numba.njit(cache=True, inline="always")
def _trace_shapes(boxes, cyls, n_spheres, ox, oy, oz, dx, dy, dz, t_best, hit):
    """Nearer box or cylinder hit than ``(t_best, hit)`` of a ray from ``o``: ``(t, hit)``.

    Boxes are hit codes ``n_spheres + j``, cylinders ``n_spheres + n_boxes + m``.
    """
    n_boxes = boxes.shape[0]
    for j in range(n_boxes):
        t_near = -np.inf
        t_far = np.inf
        for a in range(3):
            o = (ox, oy, oz)[a] - boxes[j, a]
            d = (dx, dy, dz)[a]
            h = boxes[j, 3 + a]
            if d == 0.0:
                if abs(o) > h:
                    t_near = np.inf
                continue
            t1 = (-h - o) / d
            t2 = (h - o) / d
            if t1 > t2:
                t1, t2 = t2, t1
            t_near = max(t_near, t1)
            t_far = min(t_far, t2)
        if t_near <= t_far:
            t = t_near if t_near > 1e-6 else t_far  # inside the box: its far wall
            if 1e-6 < t < t_best:
                t_best = t
                hit = n_spheres + j
    for m in range(cyls.shape[0]):
        px = ox - cyls[m, 0]
        py = oy - cyls[m, 1]
        pz = oz - cyls[m, 2]
        r = cyls[m, 3]
        hh = cyls[m, 4]
        a2 = dx * dx + dy * dy
        if a2 > 0.0:
            b = px * dx + py * dy
            disc = b * b - a2 * (px * px + py * py - r * r)
            if disc >= 0.0:
                sq = math.sqrt(disc)
                for t in ((-b - sq) / a2, (-b + sq) / a2):
                    if 1e-6 < t < t_best and abs(pz + t * dz) <= hh:
                        t_best = t
                        hit = n_spheres + n_boxes + m
                        break
        if dz != 0.0:
            for cap in (-hh, hh):
                t = (cap - pz) / dz
                if 1e-6 < t < t_best:
                    qx = px + t * dx
                    qy = py + t * dy
                    if qx * qx + qy * qy <= r * r:
                        t_best = t
                        hit = n_spheres + n_boxes + m
    return t_best, hit


@numba.njit(cache=True, inline="always")
def _noise_hash(h):
    """Sensor-noise hash to a float in [0, 1), given the pre-mixed sum ``h`` (any int64).

    The hash of four ints ``(a, b, c, d)`` is this finaliser applied to
    ``a·0x27D4EB2D + b·0x165667B1 + c·0x9E3779B1 + d·0x85EBCA77`` (low 32 bits); the kernel
    forms the sum incrementally (per frame, row and column).
    """
    h &= 0xFFFFFFFF
    h ^= h >> 15
    h = (h * 0x2C1B3C6D) & 0xFFFFFFFF
    h ^= h >> 12
    h = (h * 0x297A2D39) & 0xFFFFFFFF
    h ^= h >> 15
    return h / 4294967296.0


@numba.njit(cache=True, inline="always")
def _obstacle_grey(tex, contrast, nx, ny, nz):
    """Grey value of an obstacle surface: texture (scaled by the material's contrast about
    its mean) times Lambert shading of the unit normal ``n``."""
    lx, ly, lz = 0.36, 0.48, -0.8  # unit vector towards the light (north-east, above), NED
    if contrast != 1.0:
        tex = 0.5 + contrast * (tex - 0.5)
    lambert = nx * lx + ny * ly + nz * lz
    shade = 0.45 + 0.55 * max(lambert, 0.0)
    return 10.0 + 235.0 * shade * (0.15 + 0.85 * tex)


@numba.njit(cache=True, inline="always")
def _shade(
    lat,
    spheres,
    boxes,
    cyls,
    hit,
    t_best,
    ox,
    oy,
    oz,
    dx,
    dy,
    dz,
    aa,
    fx,
    texture_cell,
    ground_cell,
    ground_seed,
):
    """Grey value (before noise) of a ray from ``o`` that hit obstacle ``hit`` >= 0 or the
    ground (-1).

    Each branch only picks the texture's plane coordinates, seed and normal: the texture
    and the shading are written once (inlined into the renderer's loop, every call site of
    a texture multiplies numba's compile time, not the speed)."""
    lz = -0.8
    footprint = t_best / fx * math.sqrt(aa)
    n_spheres = spheres.shape[0]
    n_boxes = boxes.shape[0]
    if hit >= 0 and hit < n_spheres:
        px = ox + t_best * dx - spheres[hit, 0]
        py = oy + t_best * dy - spheres[hit, 1]
        pz = oz + t_best * dz - spheres[hit, 2]
        r = spheres[hit, 3]
        tex = _sphere_texture(lat, px, py, pz, texture_cell, footprint, spheres[hit, 4])
        return _obstacle_grey(tex, spheres[hit, 5], px / r, py / r, pz / r)
    cell = texture_cell
    if hit >= n_spheres and hit < n_spheres + n_boxes:
        j = hit - n_spheres
        p0 = ox + t_best * dx - boxes[j, 0]
        p1 = oy + t_best * dy - boxes[j, 1]
        p2 = oz + t_best * dz - boxes[j, 2]
        # The face hit is the axis where the point is nearest the box's half-size.
        f0 = abs(p0) / boxes[j, 3]
        f1 = abs(p1) / boxes[j, 4]
        f2 = abs(p2) / boxes[j, 5]
        seed = boxes[j, 6]
        contrast = boxes[j, 7]
        if f0 >= f1 and f0 >= f2:
            a, b, nx, ny, nz = p1, p2, math.copysign(1.0, p0), 0.0, 0.0
        elif f1 >= f2:
            a, b, seed, nx, ny, nz = p0, p2, seed + 2.0, 0.0, math.copysign(1.0, p1), 0.0
        else:
            a, b, seed, nx, ny, nz = p0, p1, seed + 4.0, 0.0, 0.0, math.copysign(1.0, p2)
    elif hit >= 0:
        m = hit - n_spheres - n_boxes
        px = ox + t_best * dx - cyls[m, 0]
        py = oy + t_best * dy - cyls[m, 1]
        pz = oz + t_best * dz - cyls[m, 2]
        r = cyls[m, 3]
        seed = cyls[m, 5]
        contrast = cyls[m, 6]
        radial = math.sqrt(px * px + py * py)
        if abs(pz) >= cyls[m, 4] - 1e-6 and radial < r * (1.0 - 1e-6):  # a cap
            a, b, seed, nx, ny, nz = px, py, seed + 2.0, 0.0, 0.0, math.copysign(1.0, pz)
        else:
            a, b, nx, ny, nz = r * math.atan2(py, px), pz, px / r, py / r, 0.0
    else:  # the ground
        a, b, cell, seed = ox + t_best * dx, oy + t_best * dy, ground_cell, ground_seed
        contrast, nx, ny, nz = 1.0, 0.0, 0.0, 0.0
    tex = _ground_texture(lat, a, b, cell, footprint, seed)
    if hit < 0:
        return 20.0 + 200.0 * (0.2 + 0.8 * tex) * (0.45 + 0.55 * -lz)
    return _obstacle_grey(tex, contrast, nx, ny, nz)


# Fast-math flags without 'nnan'/'ninf': the sky's depth is +inf and must compare correctly.
@numba.njit(cache=True, parallel=True, fastmath={"nsz", "arcp", "contract", "afn", "reassoc"})
def _render_pair(
    left,
    right,
    depth,
    origins,
    R,
    fx,
    fy,
    cx,
    cy,
    spheres,
    boxes,
    cyls,
    has_ground,
    ground_down,
    ground_seed,
    lat,
    texture_cell,
    ground_cell,
    noise_std,
    noise_seed,
    cloud_amp,
    row_step,
    gain_right,
    depth_only,
):
    """Both eyes in one parallel pass over rows; ray directions and the sky are shared.

    With ``depth_only`` only the left eye's true depth is traced (no second eye, no
    shading, no noise; ``left`` and ``right`` are left as they are): the ground-truth
    perception of the lockstep harness needs nothing else.

    The eyes differ only in their origins (``origins[0]`` left, ``origins[1]`` right): a
    pixel's ray direction, and hence the sky (at infinity), is the same for both. Rows are
    visited in the order ``v = i * row_step mod H`` (``row_step`` coprime with ``H``) so each
    thread's contiguous share of ``i`` is spread over the whole image (sky rows are cheap,
    ground rows dear).
    """
    H, W = left.shape
    n_spheres = spheres.shape[0]
    noise_scale = noise_std * math.sqrt(6.0)
    mask = _LATTICE_MASK
    # Per eye and sphere: ray origin relative to the centre and |oc|^2 - r^2 (per frame).
    eye_sph = np.empty((2, n_spheres, 4))
    ground_ok = np.zeros(2, dtype=np.bool_)
    for e in range(2):
        for k in range(n_spheres):
            ox = origins[e, 0] - spheres[k, 0]
            oy = origins[e, 1] - spheres[k, 1]
            oz = origins[e, 2] - spheres[k, 2]
            eye_sph[e, k, 0] = ox
            eye_sph[e, k, 1] = oy
            eye_sph[e, k, 2] = oz
            eye_sph[e, k, 3] = ox * ox + oy * oy + oz * oz - spheres[k, 3] * spheres[k, 3]
        ground_ok[e] = has_ground and origins[e, 2] < ground_down
    # Noise hash (seed, eye, u, v) and (seed, eye + 2, v, u): the integer sum is linear, so
    # its per-frame and per-row parts are hoisted (exact: wrap-around arithmetic, low 32 bits).
    hash_a = np.empty(2, dtype=np.int64)
    hash_b = np.empty(2, dtype=np.int64)
    for e in range(2):
        hash_a[e] = noise_seed * 0x27D4EB2D + e * 0x165667B1
        hash_b[e] = noise_seed * 0x27D4EB2D + (e + 2) * 0x165667B1
    o0x, o0y, o0z = origins[0, 0], origins[0, 1], origins[0, 2]
    o1x, o1y, o1z = origins[1, 0], origins[1, 1], origins[1, 2]
    ground0 = ground_ok[0]
    ground1 = ground_ok[1]
    quiet = not noise_std > 0.0
    has_shapes = boxes.shape[0] + cyls.shape[0] > 0
    for i in numba.prange(H):
        v = (i * row_step) % H
        yc = (v - cy) / fy
        row_a0 = hash_a[0] + v * 0x85EBCA77
        row_a1 = hash_a[1] + v * 0x85EBCA77
        row_b0 = hash_b[0] + v * 0x9E3779B1
        row_b1 = hash_b[1] + v * 0x9E3779B1
        for u in range(W):
            xc = (u - cx) / fx
            dx = R[0, 0] * xc + R[0, 1] * yc + R[0, 2]
            dy = R[1, 0] * xc + R[1, 1] * yc + R[1, 2]
            dz = R[2, 0] * xc + R[2, 1] * yc + R[2, 2]
            aa = dx * dx + dy * dy + dz * dz
            t0, hit0 = _trace(eye_sph, 0, n_spheres, dx, dy, dz, aa)
            if has_shapes:
                t0, hit0 = _trace_shapes(
                    boxes, cyls, n_spheres, o0x, o0y, o0z, dx, dy, dz, t0, hit0
                )
            if ground0 and dz > 0.0:
                t = (ground_down - o0z) / dz
                if t < t0:
                    t0 = t
                    hit0 = -1
            if depth_only:
                depth[v, u] = t0
                continue
            t1, hit1 = _trace(eye_sph, 1, n_spheres, dx, dy, dz, aa)
            if has_shapes:
                t1, hit1 = _trace_shapes(
                    boxes, cyls, n_spheres, o1x, o1y, o1z, dx, dy, dz, t1, hit1
                )
            if ground1 and dz > 0.0:
                t = (ground_down - o1z) / dz
                if t < t1:
                    t1 = t
                    hit1 = -1
            sky = 0.0
            if hit0 == -2 or hit1 == -2:
                inv = 1.0 / math.sqrt(aa)
                sky = 185.0 - 40.0 * dz * inv  # brighter towards the zenith
                if cloud_amp > 0.0:
                    face, cs, ct = _cube_face(dx, dy, dz)
                    scale = 6.0 / max(abs(dx), abs(dy), abs(dz))
                    clouds = _value_noise2(lat, cs * scale, ct * scale, (face + 11) & mask)
                    sky += cloud_amp * (clouds - 0.5)
            value0 = sky
            if hit0 != -2:
                value0 = _shade(
                    lat,
                    spheres,
                    boxes,
                    cyls,
                    hit0,
                    t0,
                    o0x,
                    o0y,
                    o0z,
                    dx,
                    dy,
                    dz,
                    aa,
                    fx,
                    texture_cell,
                    ground_cell,
                    ground_seed,
                )
            value1 = sky
            if hit1 != -2:
                value1 = _shade(
                    lat,
                    spheres,
                    boxes,
                    cyls,
                    hit1,
                    t1,
                    o1x,
                    o1y,
                    o1z,
                    dx,
                    dy,
                    dz,
                    aa,
                    fx,
                    texture_cell,
                    ground_cell,
                    ground_seed,
                )
            value1 *= gain_right
            if not quiet:
                n1 = _noise_hash(row_a0 + u * 0x9E3779B1)
                n2 = _noise_hash(row_b0 + u * 0x85EBCA77)
                value0 += noise_scale * (n1 + n2 - 1.0)
                n1 = _noise_hash(row_a1 + u * 0x9E3779B1)
                n2 = _noise_hash(row_b1 + u * 0x85EBCA77)
                value1 += noise_scale * (n1 + n2 - 1.0)
            value0 = min(max(value0, 0.0), 255.0)
            value1 = min(max(value1, 0.0), 255.0)
            left[v, u] = np.uint8(value0 + 0.5)
            right[v, u] = np.uint8(value1 + 0.5)
            depth[v, u] = t0


def _line_kernel(length_px: float) -> np.ndarray:
    """Normalised 1-D motion-blur kernel of ``length_px`` (fractional ends weighted)."""
    n = 2 * math.ceil((length_px - 1.0) / 2.0) + 1 if length_px > 1.0 else 1
    kernel = np.ones(n, np.float32)
    if n > 1:
        kernel[[0, -1]] = 0.5 * (length_px - (n - 2))
    return kernel / kernel.sum()


def _degrade(left: np.ndarray, right: np.ndarray, p: RenderParams, seed: int):
    """The optical and transport degradations of :class:`RenderParams`, in physical order:
    misrectification and motion blur (optics), sensor noise (only here when blurred: the
    kernel adds it otherwise), then JPEG (the link). Deterministic in ``seed``."""
    import cv2  # OpenCV is already a dependency (the companion's matcher); plant-side only here

    if p.misrect_v_px != 0.0:
        shift = np.float32([[1.0, 0.0, 0.0], [0.0, 1.0, p.misrect_v_px]])
        right = cv2.warpAffine(
            right,
            shift,
            (right.shape[1], right.shape[0]),
            flags=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_REPLICATE,
        )
    if p.blur_h_px > 0.0 or p.blur_v_px > 0.0:
        kx = _line_kernel(p.blur_h_px)
        ky = _line_kernel(p.blur_v_px)
        rng = np.random.default_rng((p.lattice_seed, seed))
        out = []
        for image in (left, right):
            blurred = cv2.sepFilter2D(image.astype(np.float32), -1, kx, ky)
            if p.noise_std > 0.0:
                blurred += rng.normal(0.0, p.noise_std, blurred.shape).astype(np.float32)
            out.append(np.clip(blurred + 0.5, 0.0, 255.0).astype(np.uint8))
        left, right = out
    if p.jpeg_quality > 0:
        params = [cv2.IMWRITE_JPEG_QUALITY, p.jpeg_quality]
        left, right = (
            cv2.imdecode(cv2.imencode(".jpg", image, params)[1], cv2.IMREAD_GRAYSCALE)
            for image in (left, right)
        )
    return left, right


def _coprime_step(n: int) -> int:
    """A step near ``n / φ`` coprime with ``n``: ``i * step mod n`` permutes ``range(n)``."""
    step = max(1, round(n * 0.6180339887))
    while math.gcd(step, n) != 1:
        step += 1
    return step


class StereoCameraRenderer:
    """Renders the rectified stereo pair a vehicle's camera sees in a :class:`World`.

    Construct once (it builds the texture lattice from ``params.lattice_seed``), then call
    :meth:`render` per frame. Pure: no I/O, no clock; the same inputs give the same images.

    Parameters
    ----------
    camera : CameraModel
        Resolution, field of view, baseline.
    params : RenderParams
        Texture and noise settings.
    """

    def __init__(self, camera: CameraModel | None = None, params: RenderParams | None = None):
        self.camera = camera if camera is not None else CameraModel()
        self.params = params if params is not None else RenderParams()
        rng = np.random.default_rng(self.params.lattice_seed)
        lattice = rng.random((_LATTICE_SIZE,) * 3, dtype=np.float32)
        lattice.flags.writeable = False
        self._lattice = lattice
        self._lattice_flat = lattice.reshape(-1)  # the kernels' view: [(ix * L + iy) * L + layer]
        self._row_step = _coprime_step(self.camera.height_px)
        self._arrays_of: World | None = None
        self._arrays: tuple[np.ndarray, np.ndarray, np.ndarray] = ()  # type: ignore[assignment]

    def render(self, world: World, pos_ned_m, R_ned_from_frd, noise_seed: int = 0) -> StereoRender:
        """Render both eyes for the vehicle pose.

        Parameters
        ----------
        world : World
            Obstacles and ground.
        pos_ned_m : array_like, shape (3,)
            Body origin in LOCAL_NED [m] (the stereo pair is centred on it).
        R_ned_from_frd : array_like, shape (3, 3)
            Body FRD → NED rotation.
        noise_seed : int
            Seed of this frame's sensor noise (e.g. the frame sequence number).

        Returns
        -------
        StereoRender
            Left and right uint8 images and the left eye's true depth [m].
        """
        left, right, depth = self._cast(world, pos_ned_m, R_ned_from_frd, noise_seed, False)
        p = self.params
        if p.degraded:
            left, right = _degrade(left, right, p, int(noise_seed) & 0x7FFFFFFF)
        return StereoRender(left=left, right=right, depth_left_m=depth)

    def render_depth(self, world: World, pos_ned_m, R_ned_from_frd) -> np.ndarray:
        """The left eye's true depth alone, ``(H, W)`` float32 [m] along the optical axis,
        ``inf`` for sky: :meth:`render`'s ``depth_left_m`` without the images (one eye, no
        shading; several times cheaper), for ground-truth perception."""
        return self._cast(world, pos_ned_m, R_ned_from_frd, 0, True)[2]

    def _world_arrays(self, world: World) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The kernel's per-obstacle rows (spheres, boxes, cylinders); built once per world
        (a :class:`World` is immutable, so the last one's rows are reused)."""
        if self._arrays_of is world:
            return self._arrays
        spheres = np.array(
            [
                (*s.center_ned_m, s.radius_m, 7 * s.texture_seed + 3 * i, s.material.contrast)
                for i, s in enumerate(world.spheres)
            ],
            dtype=np.float64,
        ).reshape(-1, 6)
        boxes = np.array(
            [
                (
                    *b.center_ned_m,
                    *(0.5 * np.asarray(b.size_m)),
                    5 * b.texture_seed + 3 * i + 13,
                    b.material.contrast,
                )
                for i, b in enumerate(world.boxes)
            ],
            dtype=np.float64,
        ).reshape(-1, 8)
        cyls = np.array(
            [
                (
                    *c.center_ned_m,
                    c.radius_m,
                    0.5 * c.height_m,
                    5 * c.texture_seed + 3 * i + 17,
                    c.material.contrast,
                )
                for i, c in enumerate(world.cylinders)
            ],
            dtype=np.float64,
        ).reshape(-1, 7)
        for rows in (spheres, boxes, cyls):
            rows.flags.writeable = False
        self._arrays_of, self._arrays = world, (spheres, boxes, cyls)
        return self._arrays

    def _cast(self, world: World, pos_ned_m, R_ned_from_frd, noise_seed: int, depth_only: bool):
        """Run the ray caster: (left, right, depth); the images are undefined when
        ``depth_only``."""
        cam = self.camera
        R_frd = np.asarray(R_ned_from_frd, dtype=np.float64)
        pos = np.asarray(pos_ned_m, dtype=np.float64).reshape(3)
        R_ned_cam = np.ascontiguousarray(R_frd @ R_FRD_FROM_CAM)
        spheres, boxes, cyls = self._world_arrays(world)
        ground = world.ground
        has_ground = ground is not None
        ground_down = ground.down_m if ground is not None else 0.0
        ground_seed = 9.0 * ground.texture_seed if ground is not None else 0.0
        shape = (cam.height_px, cam.width_px)
        left = np.empty(shape, dtype=np.uint8)
        right = np.empty(shape, dtype=np.uint8)
        depth = np.empty(shape, dtype=np.float32)
        p = self.params
        blurred = p.blur_h_px > 0.0 or p.blur_v_px > 0.0
        seed = int(noise_seed) & 0x7FFFFFFF
        half_b = 0.5 * cam.baseline_m
        # left eye (reference) then right eye, at body y = -b/2 and +b/2
        origins = np.array([pos - half_b * R_frd[:, 1], pos + half_b * R_frd[:, 1]])
        _render_pair(
            left,
            right,
            depth,
            origins,
            R_ned_cam,
            cam.fx_px,
            cam.fy_px,
            cam.cx_px,
            cam.cy_px,
            spheres,
            boxes,
            cyls,
            has_ground,
            ground_down,
            ground_seed,
            self._lattice_flat,
            p.texture_cell_m,
            p.ground_cell_m,
            0.0 if blurred else p.noise_std,
            seed,
            p.sky_cloud_amplitude,
            self._row_step,
            float(p.gain_right),
            bool(depth_only),
        )
        return left, right, depth
