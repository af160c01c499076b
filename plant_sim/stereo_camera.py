"""Synthetic rectified stereo camera: ray-cast textured spheres, ground and sky (numba).

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

__all__ = ["RenderParams", "StereoCameraRenderer", "StereoRender"]

_LATTICE_SIZE = 32  # cells per lattice axis (power of two: indices wrap with & (L - 1))
_LATTICE_MASK = _LATTICE_SIZE - 1  # a compile-time constant: masked indices are provably >= 0


@dataclass(frozen=True)
class RenderParams:
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
    """

    texture_cell_m: float = 0.03
    ground_cell_m: float = 0.05
    noise_std: float = 2.0
    sky_cloud_amplitude: float = 12.0
    lattice_seed: int = 12345

    def __post_init__(self) -> None:
        for name in ("texture_cell_m", "ground_cell_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be finite and positive, got {value!r}")
        for name in ("noise_std", "sky_cloud_amplitude"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} must be finite and >= 0, got {value!r}")


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
    mask = _LATTICE_MASK
    face, s, t = _cube_face(x, y, z)
    layer = (int(seed_offset) + 5 * face) & mask
    fine = 0.5
    w = _lod_weight(footprint_m, cell_m)
    if w > 0.0:
        c = 1.0 / cell_m
        fine = 0.5 + w * (_value_noise2(lat, s * c, t * c, layer) - 0.5)
    coarse = 0.5
    w = _lod_weight(footprint_m, 4.0 * cell_m)
    if w > 0.0:
        c = 0.25 / cell_m
        coarse = 0.5 + w * (_value_noise2(lat, t * c, s * c, (layer + 3) & mask) - 0.5)
    return 0.55 * fine + 0.45 * coarse


@numba.njit(cache=True, inline="always")
def _ground_texture(lat, x, y, cell_m, footprint_m, seed_offset):
    """Two octaves (cell and 4× cell) of 2-D value noise in [0, 1], level-of-detail faded."""
    mask = _LATTICE_MASK
    layer = int(seed_offset) & mask
    fine = 0.5
    w = _lod_weight(footprint_m, cell_m)
    if w > 0.0:
        c = 1.0 / cell_m
        fine = 0.5 + w * (_value_noise2(lat, x * c, y * c, layer) - 0.5)
    coarse = 0.5
    w = _lod_weight(footprint_m, 4.0 * cell_m)
    if w > 0.0:
        c = 0.25 / cell_m
        coarse = 0.5 + w * (_value_noise2(lat, y * c, x * c, (layer + 7) & mask) - 0.5)
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
def _shade(
    lat,
    spheres,
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
    """Grey value (before noise) of a ray from ``o`` that hit sphere ``hit`` ≥ 0 or ground (-1)."""
    lx, ly, lz = 0.36, 0.48, -0.8  # unit vector towards the light (north-east, above), NED
    footprint = t_best / fx * math.sqrt(aa)
    if hit >= 0:
        px = ox + t_best * dx - spheres[hit, 0]
        py = oy + t_best * dy - spheres[hit, 1]
        pz = oz + t_best * dz - spheres[hit, 2]
        r = spheres[hit, 3]
        tex = _sphere_texture(lat, px, py, pz, texture_cell, footprint, spheres[hit, 4])
        lambert = (px * lx + py * ly + pz * lz) / r
        shade = 0.45 + 0.55 * max(lambert, 0.0)
        return 10.0 + 235.0 * shade * (0.15 + 0.85 * tex)
    px = ox + t_best * dx
    py = oy + t_best * dy
    tex = _ground_texture(lat, px, py, ground_cell, footprint, ground_seed)
    return 20.0 + 200.0 * (0.2 + 0.8 * tex) * (0.45 + 0.55 * -lz)


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
):
    """Both eyes in one parallel pass over rows; ray directions and the sky are shared.

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
            if ground0 and dz > 0.0:
                t = (ground_down - o0z) / dz
                if t < t0:
                    t0 = t
                    hit0 = -1
            t1, hit1 = _trace(eye_sph, 1, n_spheres, dx, dy, dz, aa)
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
        cam = self.camera
        R_frd = np.asarray(R_ned_from_frd, dtype=np.float64)
        pos = np.asarray(pos_ned_m, dtype=np.float64).reshape(3)
        R_ned_cam = np.ascontiguousarray(R_frd @ R_FRD_FROM_CAM)
        spheres = np.array(
            [
                (*s.center_ned_m, s.radius_m, 7 * s.texture_seed + 3 * i)
                for i, s in enumerate(world.spheres)
            ],
            dtype=np.float64,
        ).reshape(-1, 5)
        ground = world.ground
        has_ground = ground is not None
        ground_down = ground.down_m if ground is not None else 0.0
        ground_seed = 9.0 * ground.texture_seed if ground is not None else 0.0
        shape = (cam.height_px, cam.width_px)
        left = np.empty(shape, dtype=np.uint8)
        right = np.empty(shape, dtype=np.uint8)
        depth = np.empty(shape, dtype=np.float32)
        p = self.params
        seed = int(noise_seed) & 0x7FFFFFFF
        origins = np.array(
            [pos + R_frd @ np.array([0.0, side * cam.baseline_m, 0.0]) for side in (-0.5, 0.5)]
        )  # left eye (reference) then right eye
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
            has_ground,
            ground_down,
            ground_seed,
            self._lattice_flat,
            p.texture_cell_m,
            p.ground_cell_m,
            p.noise_std,
            seed,
            p.sky_cloud_amplitude,
            _coprime_step(cam.height_px),
        )
        return StereoRender(left=left, right=right, depth_left_m=depth)
