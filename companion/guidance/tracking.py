"""Is the autopilot where it was told to be? The steady tracking offset (issue 31 item 4).

The envelope's margin (``EnvelopeConfig.margin_m``, 0.3 m) assumes the autopilot holds a
target to within a few centimetres. Wind against a position loop without an integral term
(the paper's LQ tracker: an offset of ``K_t w / (m k_p)``), a mis-trimmed airframe or an
estimator that pulls the vehicle off its own estimate break that assumption, and nothing
else in the companion would notice: the target stays outside every boundary while the
vehicle sits beside it.

:class:`TrackingMonitor` measures the offset where it means something — the vehicle at
rest (speed below ``rest_speed_mps``) on a target that has not moved (within
``steady_target_m``) for ``settle_s`` — and reports once when it exceeds the margin, and
again only after it has come back under half of it (hysteresis): the companion cannot
keep its clearance promise there, and says so.

Pure: positions, velocities and frame times in; a report out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["TrackingMonitor", "TrackingReport"]


@dataclass(frozen=True)
class TrackingReport:
    """A steady offset beyond the margin: ``offset_m`` from ``target_ned_m``."""

    offset_m: float
    margin_m: float
    target_ned_m: tuple[float, float, float]
    time_s: float


class TrackingMonitor:
    """Watches the steady offset between the vehicle and the target it was flying.

    Parameters
    ----------
    margin_m : float
        The clearance the envelope keeps beyond the vehicle's size [m].
    rest_speed_mps : float
        Below this speed the vehicle is at rest [m/s].
    steady_target_m : float
        A target that moved less than this is the same target [m].
    settle_s : float
        At rest on the same target this long before the offset counts [s].
    """

    def __init__(
        self,
        margin_m: float,
        *,
        rest_speed_mps: float = 0.05,
        steady_target_m: float = 0.05,
        settle_s: float = 2.0,
    ) -> None:
        self.margin_m = float(margin_m)
        self.rest_speed_mps = rest_speed_mps
        self.steady_target_m = steady_target_m
        self.settle_s = settle_s
        self.offset_m = math.nan  # the last steady offset measured [m]
        self._target: np.ndarray | None = None
        self._since_s: float | None = None
        self._reported = False

    def update(
        self, time_s: float, pos_ned_m, vel_ned_mps, flown_target_ned_m
    ) -> TrackingReport | None:
        """One frame: the vehicle's pose and the target it was flying (the previous
        command). Returns a report when the steady offset first exceeds the margin."""
        target = None if flown_target_ned_m is None else np.asarray(flown_target_ned_m, float)
        pos = np.asarray(pos_ned_m, dtype=float)
        vel = np.asarray(vel_ned_mps, dtype=float)
        if target is None or not (np.all(np.isfinite(pos)) and np.all(np.isfinite(vel))):
            self._target, self._since_s = None, None
            return None
        moved = self._target is None or float(np.linalg.norm(target - self._target)) > (
            self.steady_target_m
        )
        at_rest = float(np.linalg.norm(vel)) < self.rest_speed_mps
        if moved or not at_rest:
            self._target = target
            self._since_s = None if not at_rest else time_s
            return None
        if self._since_s is None:
            self._since_s = time_s
        if time_s - self._since_s < self.settle_s:
            return None
        self.offset_m = float(np.linalg.norm(pos - target))
        if self._reported:
            if self.offset_m < 0.5 * self.margin_m:
                self._reported = False
            return None
        if self.offset_m > self.margin_m:
            self._reported = True
            return TrackingReport(
                self.offset_m, self.margin_m, tuple(float(v) for v in target), time_s
            )
        return None
