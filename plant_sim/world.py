"""World description for the SIL plant: obstacles and ground in LOCAL_NED (pure, immutable).

Obstacles are spheres (the paper's), axis-aligned boxes (walls, buildings) and vertical
cylinders (poles, trunks); each has a :class:`Material` that sets how much texture a stereo
matcher finds on it.

The paper's scenario (§6, DESIGN.md): one sphere of radius 1.5 m centred at NED
(10, 0, −7) between the start (20, 0, −7) and the goal (0, 0, −7); see :func:`paper_world`.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from protocols.config import check_numbers, vec3

__all__ = ["Box", "Cylinder", "GroundPlane", "Material", "Sphere", "World", "paper_world"]


class Material(enum.Enum):
    """Surface appearance: the contrast of the procedural texture."""

    TEXTURED = "textured"  # full contrast (the default; what the paper's images show)
    LOW_TEXTURE = "low_texture"  # 12 % of the contrast: a few grey levels, near the noise
    TEXTURELESS = "textureless"  # no texture at all: only the smooth Lambert shading

    @property
    def contrast(self) -> float:
        """Texture contrast relative to :attr:`TEXTURED`."""
        return _CONTRAST[self]


_CONTRAST = {Material.TEXTURED: 1.0, Material.LOW_TEXTURE: 0.12, Material.TEXTURELESS: 0.0}


@dataclass(frozen=True)
class Sphere:
    """A spherical obstacle with a surface texture fixed to the sphere.

    Attributes
    ----------
    center_ned_m : tuple of 3 float
        Centre in LOCAL_NED [m].
    radius_m : float
        Radius [m], > 0.
    texture_seed : int
        Selects the procedural surface texture (different spheres look different).
    material : Material
        Texture contrast.
    """

    center_ned_m: tuple[float, float, float]
    radius_m: float
    texture_seed: int = 0
    material: Material = Material.TEXTURED

    def __post_init__(self) -> None:
        object.__setattr__(self, "center_ned_m", vec3(self.center_ned_m, "center_ned_m"))
        object.__setattr__(self, "material", Material(self.material))
        if not (math.isfinite(self.radius_m) and self.radius_m > 0.0):
            raise ValueError(f"radius_m must be finite and positive, got {self.radius_m!r}")

    def surface_distance_m(self, point_ned_m) -> float:
        """Distance from ``point_ned_m`` to the sphere's surface [m] (negative inside)."""
        # Plain floats: the harness and the truth log call this every physics sample.
        c = self.center_ned_m
        dn, de, dd = (float(point_ned_m[i]) - c[i] for i in range(3))
        return math.sqrt(dn * dn + de * de + dd * dd) - self.radius_m


@dataclass(frozen=True)
class Box:
    """An axis-aligned box in LOCAL_NED (a wall is a thin one), textured on its faces.

    Attributes
    ----------
    center_ned_m : tuple of 3 float
        Centre in LOCAL_NED [m].
    size_m : tuple of 3 float
        Full extent along north, east and down [m], each > 0.
    texture_seed : int
        Selects the procedural surface texture.
    material : Material
        Texture contrast.
    """

    center_ned_m: tuple[float, float, float]
    size_m: tuple[float, float, float]
    texture_seed: int = 0
    material: Material = Material.TEXTURED

    def __post_init__(self) -> None:
        object.__setattr__(self, "center_ned_m", vec3(self.center_ned_m, "center_ned_m"))
        object.__setattr__(self, "size_m", vec3(self.size_m, "size_m"))
        object.__setattr__(self, "material", Material(self.material))
        if min(self.size_m) <= 0.0:
            raise ValueError(f"size_m must be positive, got {self.size_m!r}")

    def surface_distance_m(self, point_ned_m) -> float:
        """Distance from ``point_ned_m`` to the box's surface [m] (negative inside)."""
        c, size = self.center_ned_m, self.size_m
        q = [abs(float(point_ned_m[i]) - c[i]) - 0.5 * size[i] for i in range(3)]
        outside = math.sqrt(sum(max(v, 0.0) ** 2 for v in q))
        return outside + min(max(q), 0.0)


@dataclass(frozen=True)
class Cylinder:
    """A vertical (NED z-axis) cylinder with flat caps: a pole, a trunk, a mast.

    Attributes
    ----------
    center_ned_m : tuple of 3 float
        Centre of the axis in LOCAL_NED [m] (half-way between the caps).
    radius_m : float
        Radius [m], > 0.
    height_m : float
        Length along NED down [m], > 0.
    texture_seed : int
        Selects the procedural surface texture.
    material : Material
        Texture contrast.
    """

    center_ned_m: tuple[float, float, float]
    radius_m: float
    height_m: float
    texture_seed: int = 0
    material: Material = Material.TEXTURED

    def __post_init__(self) -> None:
        object.__setattr__(self, "center_ned_m", vec3(self.center_ned_m, "center_ned_m"))
        object.__setattr__(self, "material", Material(self.material))
        check_numbers(self, ("radius_m", "height_m"), positive=True)

    def surface_distance_m(self, point_ned_m) -> float:
        """Distance from ``point_ned_m`` to the cylinder's surface [m] (negative inside)."""
        d = [float(point_ned_m[i]) - self.center_ned_m[i] for i in range(3)]
        radial = math.hypot(d[0], d[1]) - self.radius_m
        axial = abs(d[2]) - 0.5 * self.height_m
        outside = math.hypot(max(radial, 0.0), max(axial, 0.0))
        return outside + min(max(radial, axial), 0.0)


@dataclass(frozen=True)
class GroundPlane:
    """Flat textured ground: the plane ``z_ned = down_m``.

    Attributes
    ----------
    down_m : float
        NED down coordinate of the ground [m] (0 = the local origin's altitude).
    texture_seed : int
        Selects the procedural ground texture.
    """

    down_m: float = 0.0
    texture_seed: int = 1

    def __post_init__(self) -> None:
        if not math.isfinite(self.down_m):
            raise ValueError(f"down_m must be finite, got {self.down_m!r}")


@dataclass(frozen=True)
class World:
    """Obstacles and (optionally) the ground; everything else is open sky.

    Attributes
    ----------
    spheres : tuple of Sphere
        Spherical obstacles.
    ground : GroundPlane or None
        The ground plane, or ``None`` for none.
    boxes : tuple of Box
        Box obstacles (walls).
    cylinders : tuple of Cylinder
        Vertical cylinders (poles).
    """

    spheres: tuple[Sphere, ...] = ()
    ground: GroundPlane | None = GroundPlane()
    boxes: tuple[Box, ...] = ()
    cylinders: tuple[Cylinder, ...] = ()

    def __post_init__(self) -> None:
        for name, cls in (("spheres", Sphere), ("boxes", Box), ("cylinders", Cylinder)):
            items = tuple(getattr(self, name))
            object.__setattr__(self, name, items)
            for item in items:
                if not isinstance(item, cls):
                    raise TypeError(
                        f"{name} must hold {cls.__name__} objects, got {type(item).__name__}"
                    )

    @property
    def obstacles(self) -> tuple[Sphere | Box | Cylinder, ...]:
        """Every obstacle: spheres, then boxes, then cylinders."""
        return self.spheres + self.boxes + self.cylinders

    def surface_distance_m(self, point_ned_m) -> float:
        """Distance from ``point_ned_m`` to the nearest obstacle surface [m] (``inf`` if none;
        the ground is not an obstacle here)."""
        return self.nearest_obstacle(point_ned_m)[1]

    def nearest_obstacle(self, point_ned_m) -> tuple[int, float]:
        """(index into :attr:`obstacles`, surface distance [m]) of the obstacle nearest to
        ``point_ned_m``, whatever its shape (negative inside); (-1, inf) without obstacles."""
        best, best_m = -1, math.inf
        for i, obstacle in enumerate(self.obstacles):
            d = obstacle.surface_distance_m(point_ned_m)
            if d < best_m:
                best, best_m = i, d
        return best, best_m


def paper_world() -> World:
    """The paper's §6 scenario: a 1.5 m sphere at NED (10, 0, −7) above ground at z = 0."""
    return World(spheres=(Sphere(center_ned_m=(10.0, 0.0, -7.0), radius_m=1.5),))
