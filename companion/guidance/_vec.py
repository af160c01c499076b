"""3-vector helpers cheaper than ``np.linalg.norm`` / ``np.cross`` on shape-(3,) arrays."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["cross3", "norm3"]


def norm3(v: np.ndarray) -> float:
    """Euclidean norm of a shape-(3,) float array."""
    return math.sqrt(float(v @ v))


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product of two shape-(3,) arrays."""
    return np.array(
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ],
        dtype=float,
    )
