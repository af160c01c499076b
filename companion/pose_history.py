"""Pose history: recent positions/velocities and attitudes, interpolated at a capture time.

Pure: timestamps are frame-clock nanoseconds given by the caller (see
:mod:`companion.clock_model`). Positions and velocities (LOCAL_POSITION_NED) are
interpolated linearly, attitudes (ATTITUDE, 3-2-1 FRD → NED) by quaternion slerp. A capture
time slightly newer than the newest sample (≤ ``max_extrapolation_ns``) is extrapolated
with the velocity and the newest attitude; anything else that cannot be answered is a
:class:`PoseStatus` the caller counts and drops.
"""

from __future__ import annotations

import enum
import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from companion.pipeline import PoseAtCapture
from protocols.frames import Quat, quat_from_euler321, quat_slerp, rotation_from_quat

__all__ = [
    "PoseHistory",
    "PoseLookup",
    "PoseStatus",
]


class PoseStatus(enum.Enum):
    """Outcome of a lookup."""

    OK = "ok"  # interpolated between two samples
    EXTRAPOLATED = "extrapolated"  # slightly newer than the newest sample
    EMPTY = "empty"  # no position or no attitude yet
    TOO_OLD = "too_old"  # before the oldest sample kept
    TOO_NEW = "too_new"  # newer than the newest sample + max extrapolation

    @property
    def usable(self) -> bool:
        return self in (PoseStatus.OK, PoseStatus.EXTRAPOLATED)


@dataclass(frozen=True, eq=False)
class PoseLookup:
    """A lookup's status and, when usable, the pose."""

    status: PoseStatus
    pose: PoseAtCapture | None = None


def _bracket(samples: deque, t_ns: int):
    """(before, after) samples around ``t_ns`` (searching from the newest end)."""
    after = None
    for s in reversed(samples):
        if s[0] <= t_ns:
            return s, after
        after = s
    return None, after


class PoseHistory:
    """Ring buffers of timestamped poses; :meth:`at` answers "where was I at t?".

    Parameters
    ----------
    horizon_ns : int
        Samples older than the newest by more than this are discarded.
    max_extrapolation_ns : int
        How far past the newest sample a lookup may extrapolate.
    capacity : int
        Hard cap on samples per buffer.
    """

    def __init__(
        self,
        *,
        horizon_ns: int = 2_000_000_000,
        max_extrapolation_ns: int = 50_000_000,
        capacity: int = 1024,
    ) -> None:
        self._horizon_ns = int(horizon_ns)
        self._max_extrap_ns = int(max_extrapolation_ns)
        self._pos: deque[tuple[int, tuple[float, ...], tuple[float, ...]]] = deque(maxlen=capacity)
        self._att: deque[tuple[int, Quat]] = deque(maxlen=capacity)
        self.out_of_order = 0

    def clear(self) -> None:
        self._pos.clear()
        self._att.clear()

    @property
    def newest_ns(self) -> int | None:
        """Time of the newest complete pose (both position and attitude), or None."""
        if not self._pos or not self._att:
            return None
        return min(self._pos[-1][0], self._att[-1][0])

    def add_position(self, t_ns: int, pos_ned_m, vel_ned_mps) -> bool:
        """Add a LOCAL_POSITION_NED sample; False (counted) if not newer than the last."""
        if self._pos and t_ns <= self._pos[-1][0]:
            self.out_of_order += 1
            return False
        p = tuple(float(x) for x in pos_ned_m)
        v = tuple(float(x) for x in vel_ned_mps)
        if not all(math.isfinite(x) for x in p + v):
            return False
        self._pos.append((int(t_ns), p, v))
        self._trim(self._pos)
        return True

    def add_attitude(self, t_ns: int, roll_rad: float, pitch_rad: float, yaw_rad: float) -> bool:
        """Add an ATTITUDE sample; False (counted) if not newer than the last."""
        if self._att and t_ns <= self._att[-1][0]:
            self.out_of_order += 1
            return False
        if not all(math.isfinite(x) for x in (roll_rad, pitch_rad, yaw_rad)):
            return False
        self._att.append((int(t_ns), quat_from_euler321(roll_rad, pitch_rad, yaw_rad)))
        self._trim(self._att)
        return True

    def _trim(self, buf: deque) -> None:
        newest = buf[-1][0]
        while len(buf) > 2 and newest - buf[0][0] > self._horizon_ns:
            buf.popleft()

    def at(self, t_ns: int) -> PoseLookup:
        """Pose at ``t_ns``: interpolated, slightly extrapolated, or a reason why not."""
        if not self._pos or not self._att:
            return PoseLookup(PoseStatus.EMPTY)
        if t_ns < self._pos[0][0] or t_ns < self._att[0][0]:
            return PoseLookup(PoseStatus.TOO_OLD)
        newest = min(self._pos[-1][0], self._att[-1][0])
        if t_ns > newest + self._max_extrap_ns:
            return PoseLookup(PoseStatus.TOO_NEW)
        extrapolated = False

        p0, p1 = _bracket(self._pos, t_ns)
        if p1 is None:  # past the newest position: extrapolate with its velocity
            dt = (t_ns - p0[0]) * 1e-9
            pos = [p + v * dt for p, v in zip(p0[1], p0[2], strict=True)]
            vel = list(p0[2])
            extrapolated = extrapolated or t_ns > p0[0]
        else:
            u = (t_ns - p0[0]) / (p1[0] - p0[0])
            pos = [a + u * (b - a) for a, b in zip(p0[1], p1[1], strict=True)]
            vel = [a + u * (b - a) for a, b in zip(p0[2], p1[2], strict=True)]

        a0, a1 = _bracket(self._att, t_ns)
        if a1 is None:
            q = a0[1]
            extrapolated = extrapolated or t_ns > a0[0]
        else:
            q = quat_slerp(a0[1], a1[1], (t_ns - a0[0]) / (a1[0] - a0[0]))

        pose = PoseAtCapture(
            pos_ned_m=np.array(pos), vel_ned_mps=np.array(vel), R_ned_from_frd=rotation_from_quat(q)
        )
        return PoseLookup(PoseStatus.EXTRAPOLATED if extrapolated else PoseStatus.OK, pose)
