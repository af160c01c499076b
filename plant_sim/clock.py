"""Pacing simulation time against wall time (``--speedup N``), pure arithmetic.

Simulation time advances only when the plant steps; :class:`Pacer` says how far it may go
for a given wall-clock reading: ``sim = sim0 + speedup · (wall − wall0)``. When the plant
cannot keep up (it lags more than ``max_lag_wall_s``), the anchor moves forward instead of
letting the plant sprint to catch up, and the slip is counted — the run stays
deterministic in simulation time, only its real-time factor drops. ``speedup = inf`` means
"as fast as possible" (benchmarks).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["Pacer", "PacerStats"]


@dataclass
class PacerStats:
    """How often and by how much the plant fell behind its pace."""

    slips: int = 0
    slipped_sim_s: float = 0.0


class Pacer:
    """Maps wall time [s, monotonic] to the simulation time the plant should reach."""

    def __init__(self, speedup: float, max_lag_wall_s: float = 0.25) -> None:
        if not (speedup > 0.0):
            raise ValueError(f"speedup must be > 0, got {speedup!r}")
        self.speedup = float(speedup)
        self.max_lag_wall_s = max_lag_wall_s
        self._wall0 = 0.0
        self._sim0 = 0.0
        self.stats = PacerStats()

    @property
    def unpaced(self) -> bool:
        return math.isinf(self.speedup)

    def start(self, wall_s: float, sim_s: float) -> None:
        """Anchor: simulation time ``sim_s`` corresponds to wall time ``wall_s``."""
        self._wall0, self._sim0 = wall_s, sim_s

    def target_sim_s(self, wall_s: float, sim_now_s: float) -> float:
        """Simulation time to reach at ``wall_s``; re-anchors if the plant lags too far."""
        if self.unpaced:
            return math.inf
        target = self._sim0 + self.speedup * (wall_s - self._wall0)
        lag_sim_s = target - sim_now_s
        if lag_sim_s > self.max_lag_wall_s * self.speedup:
            self.stats.slips += 1
            self.stats.slipped_sim_s += lag_sim_s
            self.start(wall_s, sim_now_s)
            return sim_now_s
        return target

    def wall_at(self, sim_s: float) -> float:
        """Wall time at which the plant should reach ``sim_s`` (−inf when unpaced)."""
        if self.unpaced:
            return -math.inf
        return self._wall0 + (sim_s - self._sim0) / self.speedup
