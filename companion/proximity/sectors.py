"""OBSTACLE_DISTANCE sectors from the known-space map: one obstacle model for all.

The autopilot's own avoidance (ArduCopter's simple avoidance with ``PRX1_TYPE = 2``, PX4's
Collision Prevention) is told about the same world guidance avoids: the
:class:`~companion.known_space.KnownSpace` map, not perception's per-frame spheres. Pure:
no clock, no I/O; one numba kernel over the map's columns near the vehicle.

Per sector (body bearing ``θ_k = angle_offset + k · increment``, the sector
``[θ_k − increment/2, θ_k + increment/2)``, bearings clockwise from the nose, FRD):

* **Obstacle**: the horizontal distance from the vehicle to the nearest OCCUPIED voxel
  whose vertical extent overlaps the vehicle's height band (``pos_z ± band_half_height_m``:
  the vehicle's size plus a margin), out to ``max_distance_m``. A voxel counts for every
  sector its footprint touches (the disc of half the footprint's diagonal about its
  centre), at the distance of that disc's nearest point: conservative by at most
  ``voxel · (√2 − 1) / 2`` (4 cm at 0.2 m). Closed form for a long wall at distance ``d``
  whose normal points to bearing ``α``: sector ``k`` reads ``d / cos(max(0, |θ_k − α| −
  increment/2))``, the distance to the wall at the sector's edge nearest the normal.
* **Unknown** (``UINT16_MAX``): no obstacle, but some voxel of the band within
  ``max_distance_m`` in the sector is not FREE (UNKNOWN, TENTATIVE or outside the grid).
  Unknown is never clear (DESIGN.md, "The safety envelope").
* **No obstacle** (``max_distance + 1`` cm, the message's convention): the band was seen
  FREE over the whole sector out to ``max_distance_m``.

An obstacle seen beyond unknown space is reported at its distance (the autopilot learns of
it); the unknown space in front of it is not reported as an obstacle, as nowhere else.
Voxels within ``ignore_within_m`` of the vehicle (its own body) are skipped.

Frame (chosen after reading the message definition, ArduPilot's
``libraries/AP_Proximity/AP_Proximity_MAV.cpp`` and PX4's
``src/lib/collision_prevention/CollisionPrevention.cpp``): **MAV_FRAME_BODY_FRD** with
``angle_offset`` and ``increment_f``. ArduPilot ignores the message's ``frame`` field and
always reads the sectors as body-relative (sector ``j`` at ``j · increment + angle_offset``),
so a LOCAL_NED message would be misread there; PX4 reads both. The sectors are computed
in NED from the map and turned into body bearings with the vehicle's yaw. Both autopilots
drop ``0``, ``UINT16_MAX`` and anything below ``min_distance`` or above ``max_distance``,
so a real obstacle nearer than ``min_distance_m`` is reported *at* ``min_distance_m``,
never below it. PX4 bins ``[5i, 5i + 5)`` while ArduPilot centres sector ``j`` on
``5j``: with the default ``angle_offset = 0`` PX4's bins lie 2.5° clockwise of ours
(named limitation).

The reach (``max_distance_m``) is what the map can vouch for: the smaller of the range
its rays free (``KnownSpaceConfig.max_range_m`` and the depth source's trusted range) and
the distance the vehicle always has to the grid's edge (a quarter of the grid, the
recentring rule, less one voxel): 6.2 m for the 0.2 m grid. With the map's far layer
(``KnownSpaceConfig.far_range_m``, 0.4 m voxels fed by the same rays) the reach is the far
layer's (16 m): within the grid's reach the grid alone decides, beyond it the far layer's
voxels do (a far voxel counts when its footprint reaches beyond the grid's reach).

An OCCUPIED voxel up to ``unseen_extension_m`` above or below the band, joined to an
unseen voxel of the band through unseen ones, counts as in the band: what was seen of an
obstacle continues into the part of the band the camera did not see (a camera pitched by
the vehicle's speed sees only below its own altitude far ahead).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from companion.known_space import KnownSpace
from protocols.config import ConfigError, bounded, check_fields

__all__ = [
    "MAX_SECTORS",
    "UINT16_MAX",
    "ProximityConfig",
    "ProximitySectors",
    "map_reach_m",
    "sectors_from_map",
    "unknown_sectors",
]

MAX_SECTORS = 72  # OBSTACLE_DISTANCE.distances
UINT16_MAX = 65535  # "unknown / not used" in OBSTACLE_DISTANCE


@dataclass(frozen=True)
class ProximityConfig:
    """OBSTACLE_DISTANCE from the known-space map (``[proximity]`` in the config file).

    Attributes
    ----------
    enabled : bool
        Send OBSTACLE_DISTANCE (on by default, for ArduPilot and PX4 alike).
    thread : bool
        A watchdog thread sends when the main loop has sent nothing for 1.5 periods (a
        long frame, a starved processor; :mod:`companion.proximity.stream`; on by
        default). Off: the main loop alone (what a replay reproduces).
    own_process : bool
        With ``thread``: the stream runs in a process of its own
        (:mod:`companion.proximity.process`) that sends every period through the
        companion's own UDP socket (inherited through the fork: the autopilot sees one
        peer) and is that socket's only reader (its own pose from the telemetry as it
        arrives; every datagram forwarded to the main loop), so it keeps the rate and a
        fresh pose while the companion's interpreter is busy or stalled. On by
        default on ``udpout``, ``udpin`` and ``udp`` links where the system can fork; the
        watchdog thread elsewhere (serial, TCP), when off, and when the process does not
        come up (each said in the log).
    realtime_priority : int
        The process asks the kernel for ``SCHED_FIFO`` at this priority (1–99; 0: it
        stays a normal task). A normal task that sleeps 25 ms at a time still waited up
        to 1.7 s for a processor at load 20 on 2 cores (issue 34, ``bench_proximity``);
        a real-time one runs when it wakes. It needs ``CAP_SYS_NICE`` (root, or
        ``AmbientCapabilities=CAP_SYS_NICE`` / ``LimitRTPRIO`` in a systemd unit);
        without it the process says so once and runs as a normal task. The process
        sleeps between sends (~1 ms of CPU each), and the kernel's real-time throttling
        (``sched_rt_runtime_us``) bounds what a fault could take.
    rate_hz : float
        Least send rate [Hz wall]: every processed frame sends one, and a timer fills the
        gaps (before the first frame, during a takeoff, when frames stop) from the map at
        the newest telemetry pose. ArduPilot drops the data after 0.5 s, PX4 after 0.5 s.
    n_sectors : int
        Sectors in the message, ≤ 72.
    increment_deg : float
        Sector width [deg]; ``n_sectors · increment_deg`` ≤ 360.
    angle_offset_deg : float
        Body bearing of sector 0's centre [deg, clockwise from the nose].
    band_half_height_m : float
        Half-height of the vehicle's band [m]: its half-height plus a margin.
    ignore_within_m : float
        Voxels centred this close to the vehicle, horizontally, are its own body [m].
    min_distance_m : float
        The message's ``min_distance`` [m]; nearer obstacles are reported at it.
    unseen_extension_m : float
        An OCCUPIED voxel up to this far above or below the band counts as in it when no
        FREE voxel lies between it and the band's unseen voxels [m]: an obstacle seen
        only below the band continues into it until seen otherwise (the camera of a
        vehicle pitched by its speed, 20° at 8 m/s for the ``fast`` airframe, cannot see
        its own altitude ahead; Fig. 4's blind spot, upward). 0: the band alone.
    """

    enabled: bool = True
    thread: bool = True
    own_process: bool = True
    realtime_priority: int = bounded(10, integer=True, ge=0, le=99)
    rate_hz: float = bounded(20.0, "Hz", gt=0)
    n_sectors: int = bounded(72, integer=True, ge=1, le=MAX_SECTORS)
    increment_deg: float = bounded(5.0, "deg", gt=0)
    angle_offset_deg: float = bounded(0.0, "deg")
    band_half_height_m: float = bounded(0.3, "m", gt=0)
    ignore_within_m: float = bounded(0.3, "m", ge=0)
    # 0 cm is "invalid" on the wire
    min_distance_m: float = bounded(0.2, "m", ge=0.01)
    unseen_extension_m: float = bounded(1.0, "m", ge=0)

    def __post_init__(self) -> None:
        for key in ("enabled", "thread", "own_process"):
            if not isinstance(getattr(self, key), bool):
                raise ConfigError(f"must be true or false, got {getattr(self, key)!r}", key=key)
        check_fields(self)
        if self.n_sectors * self.increment_deg > 360.0 + 1e-9:
            raise ConfigError(
                f"n_sectors × increment_deg must be <= 360, got {self.n_sectors} × "
                f"{self.increment_deg}",
                key="increment_deg",
            )


@dataclass(frozen=True, eq=False)
class ProximitySectors:
    """One OBSTACLE_DISTANCE's content (MAV_FRAME_BODY_FRD).

    Attributes
    ----------
    distances_cm : ndarray, shape (72,), uint16
        Per sector [cm]; ``UINT16_MAX`` unknown (and the unused tail), ``max_distance_cm
        + 1`` no obstacle.
    increment_deg, angle_offset_deg : float
        Sector width and sector 0's centre [deg, body, clockwise].
    min_distance_cm, max_distance_cm : int
    n_sectors : int
    """

    distances_cm: np.ndarray
    increment_deg: float
    angle_offset_deg: float
    min_distance_cm: int
    max_distance_cm: int
    n_sectors: int

    @property
    def no_obstacle_cm(self) -> int:
        return self.max_distance_cm + 1

    def counts(self) -> tuple[int, int, int]:
        """(obstacle, clear, unknown) sectors."""
        d = self.distances_cm[: self.n_sectors].astype(np.int64)
        unknown = int(np.count_nonzero(d == UINT16_MAX))
        clear = int(np.count_nonzero(d == self.no_obstacle_cm))
        return self.n_sectors - unknown - clear, clear, unknown

    def bearings_deg(self) -> np.ndarray:
        """Body bearing of each sector's centre [deg, clockwise from the nose]."""
        return self.angle_offset_deg + self.increment_deg * np.arange(self.n_sectors)


def _layer_reach_m(space: KnownSpace) -> float:
    """How far [m] one layer of the map vouches for, horizontally, around the vehicle."""
    c = space.config
    in_grid_m = (c.size_xy_vox // 4 - 1) * c.voxel_m
    return float(min(space.range_m, in_grid_m))


def map_reach_m(space: KnownSpace) -> float:
    """How far [m] the map vouches for, horizontally, around the vehicle (module doc):
    its far layer's reach where it has one."""
    reach = _layer_reach_m(space)
    return reach if space.far is None else max(reach, _layer_reach_m(space.far))


def unknown_sectors(config: ProximityConfig, max_distance_m: float) -> ProximitySectors:
    """Every sector unknown: what is honest before the map has anything."""
    return ProximitySectors(
        np.full(MAX_SECTORS, UINT16_MAX, np.uint16),
        float(config.increment_deg),
        float(config.angle_offset_deg),
        _cm(config.min_distance_m),
        _cm(max_distance_m),
        config.n_sectors,
    )


def sectors_from_map(
    space: KnownSpace, pos_ned_m, yaw_rad: float, config: ProximityConfig
) -> ProximitySectors:
    """The sectors around ``pos_ned_m`` with the vehicle's nose at ``yaw_rad`` (NED).

    Parameters
    ----------
    space : KnownSpace
    pos_ned_m : array_like, shape (3,)
        Vehicle position [m, LOCAL_NED].
    yaw_rad : float
        Vehicle heading [rad, NED, clockwise from north].
    config : ProximityConfig
    """
    reach_m = map_reach_m(space)
    p = np.asarray(pos_ned_m, dtype=float)
    if p.shape != (3,) or not np.all(np.isfinite(p)) or not math.isfinite(yaw_rad):
        raise ValueError(f"position and yaw must be finite, got {pos_ned_m!r}, {yaw_rad!r}")
    occupied = np.full(config.n_sectors, np.inf)
    unknown = np.full(config.n_sectors, np.inf)
    # the grid out to its reach, then the far layer's voxels that reach beyond it
    layers = [(space, _layer_reach_m(space), -1.0)]
    if space.far is not None:
        layers.append((space.far, _layer_reach_m(space.far), layers[0][1]))
    for layer, layer_reach_m, beyond_m in layers:
        _scan(
            layer.grid,
            layer.origin_vox,
            float(layer.config.voxel_m),
            float(p[0]),
            float(p[1]),
            float(p[2]),
            float(yaw_rad),
            float(config.band_half_height_m),
            float(config.ignore_within_m),
            layer_reach_m,
            beyond_m,
            float(config.unseen_extension_m),
            math.radians(config.increment_deg),
            math.radians(config.angle_offset_deg),
            occupied,
            unknown,
        )
    min_cm, max_cm = _cm(config.min_distance_m), _cm(reach_m)
    out = np.full(MAX_SECTORS, UINT16_MAX, np.uint16)
    for k in range(config.n_sectors):
        if occupied[k] <= reach_m:
            out[k] = min(max(math.floor(occupied[k] * 100.0), min_cm), max_cm)
        elif unknown[k] > reach_m:
            out[k] = max_cm + 1
    return ProximitySectors(
        out,
        float(config.increment_deg),
        float(config.angle_offset_deg),
        min_cm,
        max_cm,
        config.n_sectors,
    )


def _cm(value_m: float) -> int:
    return round(value_m * 100.0)


@numba.njit(cache=True, nogil=True)
def _scan(
    grid,
    origin,
    voxel,
    px,
    py,
    pz,
    yaw,
    half_band,
    ignore_within,
    reach,
    beyond,
    extension,
    inc,
    offset,
    occ,
    unk,
):
    """Nearest OCCUPIED (``occ``) and not-FREE (``unk``) voxel column of the band per
    sector [m, horizontal, the footprint's nearest point], lowered where nearer than
    already there; see the module docstring. Columns whose footprint lies entirely within
    ``beyond`` [m] of the vehicle are skipped (a finer layer covered them); an OCCUPIED
    voxel within ``extension`` [m] of the band joined to its unseen voxels by unseen ones
    counts as in the band (``ProximityConfig.unseen_extension_m``)."""
    n = occ.shape[0]
    n_full = math.floor(2.0 * math.pi / inc + 1e-6)
    inv = 1.0 / voxel
    half = 0.5 * voxel
    r_vox = math.ceil((reach + voxel) * inv) + 1
    ci = math.floor(px * inv) - origin[0]
    cj = math.floor(py * inv) - origin[1]
    k_lo = math.floor((pz - half_band) * inv) - origin[2]
    k_hi = math.floor((pz + half_band) * inv) - origin[2]
    n_ext = math.ceil(extension * inv - 1e-9)
    ni, nj, nk = grid.shape
    for i in range(ci - r_vox, ci + r_vox + 1):
        dn = (i + origin[0] + 0.5) * voxel - px
        gap_n = max(abs(dn) - half, 0.0)
        for j in range(cj - r_vox, cj + r_vox + 1):
            de = (j + origin[1] + 0.5) * voxel - py
            gap_e = max(abs(de) - half, 0.0)
            near = math.sqrt(gap_n * gap_n + gap_e * gap_e)  # the footprint's nearest point
            if near > reach or dn * dn + de * de < ignore_within * ignore_within:
                continue
            if beyond >= 0.0:
                far_n = abs(dn) + half
                far_e = abs(de) + half
                if far_n * far_n + far_e * far_e <= beyond * beyond:
                    continue
            is_occ = False
            is_unk = i < 0 or j < 0 or i >= ni or j >= nj
            if not is_unk:
                for k in range(k_lo, k_hi + 1):
                    if k < 0 or k >= nk:
                        is_unk = True
                        continue
                    s = grid[i, j, k]
                    if s == 2:
                        is_occ = True
                    elif s != 1:
                        is_unk = True
                if is_unk and not is_occ and n_ext > 0:
                    is_occ = _joined(grid, i, j, k_lo, -1, n_ext) or _joined(
                        grid, i, j, k_hi, 1, n_ext
                    )
            if not (is_occ or is_unk):
                continue
            if near > 0.0:
                # the footprint's angular span: its corners' bearings about its centre's,
                # relative to sector 0's centre
                centre = math.atan2(de, dn)
                lo = 0.0
                hi = 0.0
                for cn in (dn - half, dn + half):
                    for ce in (de - half, de + half):
                        a = math.atan2(ce, cn) - centre
                        a -= 2.0 * math.pi * math.floor((a + math.pi) / (2.0 * math.pi))
                        lo = min(lo, a)
                        hi = max(hi, a)
                rel = centre - yaw - offset
                s_lo = math.floor((rel + lo) / inc + 0.5)
                s_hi = math.floor((rel + hi) / inc + 0.5)
            else:  # the vehicle stands on the footprint: every direction
                s_lo = 0
                s_hi = n_full - 1
            for s in range(s_lo, s_hi + 1):
                kk = s % n_full
                if kk >= n:
                    continue
                if is_occ and near < occ[kk]:
                    occ[kk] = near
                if is_unk and near < unk[kk]:
                    unk[kk] = near


@numba.njit(cache=True, nogil=True)
def _joined(grid, i, j, k_edge, step, n_ext):
    """An OCCUPIED voxel of column (``i``, ``j``) within ``n_ext`` voxels beyond the band's
    edge voxel ``k_edge`` (``step`` -1: up, 1: down), reached from it through voxels that
    are not FREE (the edge voxel included)."""
    nk = grid.shape[2]
    for n in range(n_ext + 1):
        k = k_edge + step * n
        if k < 0 or k >= nk:
            return False
        s = grid[i, j, k]
        if s == 2:
            return True
        if s == 1:
            return False
    return False
