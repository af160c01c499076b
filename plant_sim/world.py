"""World description for the SIL plant: obstacles and ground in LOCAL_NED (pure, immutable).

The paper's scenario (§6, DESIGN.md): one sphere of radius 1.5 m centred at NED
(10, 0, −7) between the start (20, 0, −7) and the goal (0, 0, −7); see :func:`paper_world`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["GroundPlane", "Sphere", "World", "paper_world"]


def _finite_vec3(name: str, value) -> tuple[float, float, float]:
    vec = tuple(float(x) for x in value)
    if len(vec) != 3 or not all(math.isfinite(x) for x in vec):
        raise ValueError(f"{name} must be 3 finite numbers, got {value!r}")
    return vec  # type: ignore[return-value]


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
    """

    center_ned_m: tuple[float, float, float]
    radius_m: float
    texture_seed: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "center_ned_m", _finite_vec3("center_ned_m", self.center_ned_m))
        if not (math.isfinite(self.radius_m) and self.radius_m > 0.0):
            raise ValueError(f"radius_m must be finite and positive, got {self.radius_m!r}")

    def surface_distance_m(self, point_ned_m) -> float:
        """Distance from ``point_ned_m`` to the sphere's surface [m] (negative inside)."""
        d = np.asarray(point_ned_m, dtype=float) - np.asarray(self.center_ned_m)
        return float(np.linalg.norm(d)) - self.radius_m


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
    """

    spheres: tuple[Sphere, ...] = ()
    ground: GroundPlane | None = GroundPlane()

    def __post_init__(self) -> None:
        object.__setattr__(self, "spheres", tuple(self.spheres))
        for sphere in self.spheres:
            if not isinstance(sphere, Sphere):
                raise TypeError(f"spheres must hold Sphere objects, got {type(sphere).__name__}")


def paper_world() -> World:
    """The paper's §6 scenario: a 1.5 m sphere at NED (10, 0, −7) above ground at z = 0."""
    return World(spheres=(Sphere(center_ned_m=(10.0, 0.0, -7.0), radius_m=1.5),))
