"""Size, resolution and update rules of the known-space map (:mod:`companion.known_space`)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

from protocols.config import ConfigError, bounded, check_fields, dataclass_from_mapping

__all__ = ["KnownSpaceConfig"]


@dataclass(frozen=True)
class KnownSpaceConfig:
    """Size, resolution and update rules of the known-space map.

    Attributes
    ----------
    voxel_m : float
        Voxel edge [m].
    size_xy_vox, size_z_vox : int
        Grid size in voxels, north/east and down (default 128 × 128 × 64: 25.6 × 25.6 ×
        12.8 m at 0.2 m, 1 MiB).
    max_range_m : float
        Rays certify free space up to this range [m]; hits beyond it are not obstacles.
        Must exceed the distance the vehicle needs to stop from its highest speed plus
        the range at which the top of the tube ahead enters the view (see the module
        docstring of :mod:`companion.guidance.envelope`).
    pixel_stride : int
        One ray per n × n pixel block (4 → 4 800 rays at 320 × 240).
    block_min_matched : float
        Fraction of a block's pixels that must be matched for its ray to be cast (to the
        nearest of them); fewer is unknown (or open sky).
    hit_clear_m : float
        Free marking stops this far before a hit [m] (range noise must not clear the
        surface voxel).
    clear_core_m : float
        An OCCUPIED or TENTATIVE voxel is seen free again only by a ray that passes this
        close to its centre [m] (a ray through a corner of the voxel saw the corner free,
        not the surface point in it: the flank of an obstacle beside the vehicle is
        grazed by the rays at the edge of the view in every frame). 0.06 m: at the 8 m
        range, rays 4 px apart are 9 cm apart, so a voxel seen through from anywhere
        nearer is crossed within 6 cm of its centre.
    free_core_m : float
        An UNKNOWN voxel is seen free only by a ray that passes this close to its centre
        [m] (see ``clear_core_m``; a voxel's half diagonal, 0.173 m at 0.2 m, frees every
        voxel crossed). 0.1 m, half a voxel: rays 4 px apart are 9 cm apart at the 8 m
        range, so every voxel in the view has a ray this close to its centre, and a voxel
        centre seen free lies at most 0.1 m inside an obstacle whose limb a ray grazed.
    sky_min_elevation_deg : float
        Open-sky rule: lowest ray elevation above the horizon [deg] (negative: below).
    ego_clear_radius_m : float
        OCCUPIED voxels centred within this distance of the vehicle become FREE (the
        vehicle is there) [m].
    start_free_radius_m : float
        On the first frame, voxels within this distance become FREE [m] (assumption).
    piece_vox : int
        Edge of the cubes that cut OCCUPIED voxels into pieces [voxels], even (6 → 1.2 m:
        a piece's cells lie within 1.04 m of its centroid; its eight sub-pieces are cubes
        of half the edge); see :meth:`KnownSpace.pieces`.
    blind_depth_m : float
        Deepest blind spot assumed behind a piece, away from the viewer (Fig. 4) [m];
        it ends earlier where the map has seen the space free.
    far_range_m : float
        Reach of the far layer [m] (0: none): the same depth rays folded, by the same
        rules, into a coarser vehicle-centred grid that reaches this far (``KnownSpace.far``,
        :meth:`far_config`). Only the proximity sectors read it, beyond the grid's own
        reach (an autopilot's avoidance needs to hear of a wall from its stopping distance
        at the pilot's speed: 13-14 m at 8 m/s); guidance and the envelope never do.
    far_voxel_m : float
        The far layer's voxel edge [m].
    confirm_disparity_px : float
        Range-aware occupancy: a hit is *near* when a disparity error of this many pixels
        moves it by at most a voxel, i.e. from a range ``r ≤ √(voxel · f · b / px)``
        (3.8 m at 1 px with the paper's camera, f·b = 71.9 px·m: at 8 m one pixel is
        0.89 m). An OCCUPIED voxel never hit from near does not count as a surface
        seen near (:meth:`KnownSpace.seen_near`, what latches a goal as unreachable).
        0: every hit is near (the far layer's rule).
    """

    voxel_m: float = bounded(0.2, "m", gt=0)
    size_xy_vox: int = bounded(128, "voxel", integer=True, ge=8)
    size_z_vox: int = bounded(64, "voxel", integer=True, ge=8)
    max_range_m: float = bounded(8.0, "m", gt=0)
    pixel_stride: int = bounded(4, "px", integer=True, ge=1)
    block_min_matched: float = bounded(0.25, gt=0, le=1)
    hit_clear_m: float = bounded(0.2, "m", ge=0)
    clear_core_m: float = bounded(0.06, "m", ge=0)
    # free_core_m = 0 would free nothing the camera sees: a vehicle that never moves
    free_core_m: float = bounded(0.1, "m", gt=0)
    sky_min_elevation_deg: float = bounded(-5.0, "deg", ge=-90, le=90)
    ego_clear_radius_m: float = bounded(0.25, "m", ge=0)
    start_free_radius_m: float = bounded(1.2, "m", ge=0)
    piece_vox: int = bounded(6, "voxel", integer=True, ge=2)
    blind_depth_m: float = bounded(1.2, "m", ge=0)
    far_range_m: float = bounded(16.0, "m", ge=0)
    far_voxel_m: float = bounded(0.4, "m", gt=0)
    confirm_disparity_px: float = bounded(1.0, "px", ge=0)

    def __post_init__(self) -> None:
        check_fields(self)
        if self.piece_vox % 2:
            raise ConfigError(f"must be even, got {self.piece_vox}", key="piece_vox")
        if self.far_range_m > 0.0 and self.far_voxel_m < self.voxel_m:
            raise ConfigError(
                f"must not be finer than voxel_m {self.voxel_m}, got {self.far_voxel_m}",
                key="far_voxel_m",
            )

    def far_config(self) -> KnownSpaceConfig | None:
        """The far layer's configuration (None without one): ``far_voxel_m`` voxels, a grid
        whose recentring rule keeps ``far_range_m`` inside it, rays to ``far_range_m``, the
        same height in metres, and the lengths that follow the voxel (ray cores, the clear
        distance before a hit) scaled with it. Its rays are twice as sparse (a quarter of
        the cost): 8 px apart, 0.36 m at 16 m with the paper's camera, so a far voxel is
        freed by a ray passing within 0.65 of its edge (0.26 m at 0.4 m) of its centre, the
        farthest a voxel centre in the view can be from the nearest ray."""
        if self.far_range_m <= 0.0:
            return None
        scale = self.far_voxel_m / self.voxel_m
        return replace(
            self,
            voxel_m=self.far_voxel_m,
            size_xy_vox=4 * (math.ceil(self.far_range_m / self.far_voxel_m) + 1),
            size_z_vox=max(8, math.ceil(self.size_z_vox / scale)),
            max_range_m=self.far_range_m,
            pixel_stride=2 * self.pixel_stride,
            hit_clear_m=self.hit_clear_m * scale,
            clear_core_m=self.clear_core_m * scale,
            free_core_m=max(self.free_core_m * scale, 0.65 * self.far_voxel_m),
            far_range_m=0.0,
            confirm_disparity_px=0.0,  # the proximity sectors' layer: occupancy as before
        )

    @classmethod
    def from_dict(cls, values: Mapping[str, Any], where: str = "known_space") -> KnownSpaceConfig:
        """Build from a mapping; unknown keys and values out of bounds raise
        :class:`~protocols.config.ConfigError` naming the key."""
        return dataclass_from_mapping(cls, values, where)
