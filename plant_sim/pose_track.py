"""An external autopilot's pose, interpolated to the camera's capture times (camera-only mode).

Pure: LOCAL_POSITION_NED and ATTITUDE samples go in with their autopilot ``time_boot_ms``
(as seconds); :meth:`PoseTrack.due_frames` says which capture times (``k / rate_hz`` on the
autopilot's clock) are now bracketed by samples on both sides, and :meth:`PoseTrack.at`
interpolates the pose there (position and velocity linearly, attitude by quaternion slerp,
MAVLink 3-2-1 angles, NED/FRD). A capture time is *due* once the newest position and the
newest attitude are both at or past it, so a frame is never rendered from an extrapolated
pose; a capture time that falls in a gap longer than ``max_gap_s`` between samples is
skipped and counted, never interpolated across.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from protocols.frames import Quat, quat_from_euler321, quat_slerp, rotation_from_quat

__all__ = ["ExternalPose", "PoseTrack"]


@dataclass(frozen=True)
class ExternalPose:
    """The vehicle at one instant of the autopilot's clock (NED/FRD, SI units)."""

    time_s: float  # autopilot boot time [s]
    pos_ned_m: np.ndarray
    vel_ned_mps: np.ndarray
    R_ned_from_frd: np.ndarray

    @property
    def roll_pitch_yaw_rad(self) -> tuple[float, float, float]:
        """MAVLink 3-2-1 angles of :attr:`R_ned_from_frd` [rad]."""
        R = self.R_ned_from_frd
        roll = math.atan2(R[2, 1], R[2, 2])
        pitch = -math.asin(max(-1.0, min(1.0, R[2, 0])))
        yaw = math.atan2(R[1, 0], R[0, 0])
        return roll, pitch, yaw


def _bracket(buf: deque, t_s: float):
    """(older, newer) samples around ``t_s``; newer is None past the newest, older None
    before the oldest (the newest samples are searched first)."""
    older = newer = None
    for sample in reversed(buf):
        if sample[0] > t_s:
            newer = sample
            continue
        older = sample
        break
    return older, newer


class PoseTrack:
    """Recent pose samples of an external autopilot and the frame schedule over them.

    Parameters
    ----------
    frame_rate_hz : float
        Capture times are ``k / frame_rate_hz`` seconds of the autopilot's clock.
    max_gap_s : float
        Samples further apart than this are not interpolated between [s autopilot time].
    horizon_s : float
        Samples older than the newest by more than this are discarded.
    """

    def __init__(
        self, frame_rate_hz: float, *, max_gap_s: float = 0.25, horizon_s: float = 2.0
    ) -> None:
        if not (math.isfinite(frame_rate_hz) and frame_rate_hz > 0):
            raise ValueError(f"frame rate must be > 0, got {frame_rate_hz!r}")
        if not max_gap_s > 0 or not horizon_s > max_gap_s:
            raise ValueError("need 0 < max_gap_s < horizon_s")
        self.frame_rate_hz = float(frame_rate_hz)
        self.max_gap_s = float(max_gap_s)
        self.horizon_s = float(horizon_s)
        self._pos: deque[tuple[float, tuple[float, ...], tuple[float, ...]]] = deque()
        self._att: deque[tuple[float, Quat]] = deque()
        self._next: dict[float, int] = {}  # rate [Hz] → index k of its next time
        self.rejected = 0  # non-finite or out-of-order samples
        self.frames_skipped = 0  # capture times inside a gap

    # ---- input --------------------------------------------------------------------
    def add_position(self, t_s: float, pos_ned_m, vel_ned_mps) -> bool:
        """A LOCAL_POSITION_NED sample; False (counted) if non-finite or not newer."""
        p = tuple(float(x) for x in pos_ned_m)
        v = tuple(float(x) for x in vel_ned_mps)
        if not (math.isfinite(t_s) and all(math.isfinite(x) for x in p + v)) or (
            self._pos and t_s <= self._pos[-1][0]
        ):
            self.rejected += 1
            return False
        self._pos.append((float(t_s), p, v))
        self._trim(self._pos)
        return True

    def add_attitude(self, t_s: float, roll_rad: float, pitch_rad: float, yaw_rad: float) -> bool:
        """An ATTITUDE sample; False (counted) if non-finite or not newer."""
        if not all(math.isfinite(x) for x in (t_s, roll_rad, pitch_rad, yaw_rad)) or (
            self._att and t_s <= self._att[-1][0]
        ):
            self.rejected += 1
            return False
        self._att.append((float(t_s), quat_from_euler321(roll_rad, pitch_rad, yaw_rad)))
        self._trim(self._att)
        return True

    def reset(self) -> None:
        """Forget everything (the autopilot restarted: its clock began again)."""
        self._pos.clear()
        self._att.clear()
        self._next.clear()

    def _trim(self, buf: deque) -> None:
        newest = buf[-1][0]
        while len(buf) > 2 and newest - buf[0][0] > self.horizon_s:
            buf.popleft()

    # ---- queries ------------------------------------------------------------------
    @property
    def newest_s(self) -> float | None:
        """Newest instant covered by both a position and an attitude sample."""
        if not self._pos or not self._att:
            return None
        return min(self._pos[-1][0], self._att[-1][0])

    def due_frames(self) -> list[float]:
        """Capture times [s] now covered by samples on both sides, oldest first.

        Each is returned once; capture times in a gap are skipped (:attr:`frames_skipped`).
        """
        due, skipped = self.due_times(self.frame_rate_hz)
        self.frames_skipped += skipped
        return due

    def due_times(self, rate_hz: float) -> tuple[list[float], int]:
        """Times ``k / rate_hz`` [s] newly covered by samples on both sides, and how many
        were skipped (inside a gap). One schedule per rate; each time is returned once."""
        newest = self.newest_s
        if newest is None:
            return [], 0
        oldest = max(self._pos[0][0], self._att[0][0])
        # never walk a gap time by time: a clock jump (hostile or corrupt time_boot_ms)
        # would make that loop endless; jump to the first time still worth looking at
        lower = math.ceil(max(oldest, newest - self.horizon_s) * rate_hz - 1e-9)
        k = self._next.get(rate_hz)
        due, skipped = [], 0
        if k is None:
            k = lower
        elif k < lower:
            skipped, k = lower - k, lower
        while True:
            t = k / rate_hz
            if t > newest + 1e-12:
                break
            k += 1
            if t < oldest - 1e-12 or not self._interpolable(t):
                skipped += 1
                continue
            due.append(t)
        self._next[rate_hz] = k
        return due, skipped

    def _interpolable(self, t_s: float) -> bool:
        for buf in (self._pos, self._att):
            a, b = _bracket(buf, t_s)
            if a is None:
                return False
            on_sample = t_s - a[0] <= 1e-9
            if b is not None and b[0] - a[0] > self.max_gap_s and not on_sample:
                return False
            if b is None and t_s - a[0] > 1e-9:
                return False
        return True

    def at(self, t_s: float) -> ExternalPose | None:
        """The pose at ``t_s`` interpolated between samples; None if not bracketed."""
        if not self._pos or not self._att or not self._interpolable(t_s):
            return None
        p0, p1 = _bracket(self._pos, t_s)
        if p1 is None:
            pos, vel = p0[1], p0[2]
        else:
            u = (t_s - p0[0]) / (p1[0] - p0[0])
            pos = tuple(a + u * (b - a) for a, b in zip(p0[1], p1[1], strict=True))
            vel = tuple(a + u * (b - a) for a, b in zip(p0[2], p1[2], strict=True))
        a0, a1 = _bracket(self._att, t_s)
        q = a0[1] if a1 is None else quat_slerp(a0[1], a1[1], (t_s - a0[0]) / (a1[0] - a0[0]))
        return ExternalPose(
            time_s=t_s,
            pos_ned_m=np.array(pos, dtype=float),
            vel_ned_mps=np.array(vel, dtype=float),
            R_ned_from_frd=rotation_from_quat(q),
        )
