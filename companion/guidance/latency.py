"""One latency budget: the measured age of the data behind each command (DESIGN.md envelope).

The stopping rule ``τ·v + v²/(2a) + margin ≤ F`` (:mod:`companion.guidance.envelope`) needs
``τ``, the time from the moment a frame was captured to the moment the command computed
from it acts on the vehicle. Part of it is measured per processed frame: the *data age*,
capture time → the moment the frame's setpoint leaves, on the frame clock (simulation time
in the SIL, so a slow companion at ``--speedup`` 3 counts its compute time 3×). The rest
(the autopilot's reaction once a setpoint arrives, up to one frame period) is a named
assumption, ``unmeasured_s``.

:class:`DataAgeWindow` keeps the ages of the frames captured within the last ``window_s``
and gives their high percentile; :meth:`DataAgeWindow.budget_s` is the ``τ`` the envelope
uses::

    τ = max(floor_s, P_q(ages) + unmeasured_s, current_age_s + unmeasured_s)

``floor_s`` is the configured ``EnvelopeConfig.latency_s`` (the default on an idle
computer, and ``τ`` before any age was measured); ``current_age_s`` the age the frame being
processed already has when it is handed over (a sudden stall counts at once, before it
reaches the percentile). As the pipeline slows, ``τ`` grows, and the speed limit
``v = a(−τ + √(τ² + 2(F − margin)/a))`` and the carrot shrink smoothly.

Percentile: nearest rank, the smallest sample with at least ``q`` % of the window at or
below it (a measured age, never an interpolation below the worst ones).

Pure: times are passed in; bad samples (NaN, infinite, negative: a capture time in the
future) are counted, never raised: NaN/infinite ones are dropped, negative ones count as 0
and ages above ``max_age_s`` as ``max_age_s``.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

__all__ = ["AgeStats", "DataAgeWindow", "nearest_rank_percentile"]


def nearest_rank_percentile(sorted_values, q: float) -> float:
    """Nearest-rank ``q`` percentile (0 < q ≤ 100) of ascending ``sorted_values``.

    ``sorted_values[ceil(q/100 · n) − 1]``: at least ``q`` % of the values are at or below
    it. ``nan`` for an empty sequence.
    """
    n = len(sorted_values)
    if n == 0:
        return math.nan
    rank = max(1, math.ceil(q / 100.0 * n - 1e-9))
    return float(sorted_values[min(rank, n) - 1])


@dataclass(frozen=True)
class AgeStats:
    """The window's figures (``None`` where there is no sample yet).

    Attributes
    ----------
    samples : int
        Ages in the window.
    p50_s, p99_s, budget_percentile_s : float or None
        Median, 99th and the budget's percentile of the data age [s, frame clock].
    rate_hz : float or None
        Processed frames per second of frame clock over the window [Hz].
    """

    samples: int
    p50_s: float | None
    p99_s: float | None
    budget_percentile_s: float | None
    rate_hz: float | None


class DataAgeWindow:
    """Recent data ages and the latency budget they give (see module docstring).

    Parameters
    ----------
    floor_s : float
        Smallest budget [s] (``EnvelopeConfig.latency_s``).
    window_s : float
        Frames captured this long before the newest one are forgotten [s, frame clock].
    percentile : float
        Which percentile of the window is budgeted (0 < q ≤ 100).
    unmeasured_s : float
        Latency after the setpoint leaves, added to every measured age [s].
    max_age_s : float
        Larger ages are counted as this [s] (a stalled clock must not overflow the rule).
    max_samples : int
        Bound of the window's length (oldest dropped first).
    """

    def __init__(
        self,
        floor_s: float,
        window_s: float,
        percentile: float,
        unmeasured_s: float,
        *,
        max_age_s: float = 10.0,
        max_samples: int = 512,
    ) -> None:
        self.floor_s = float(floor_s)
        self.window_s = float(window_s)
        self.percentile = float(percentile)
        self.unmeasured_s = float(unmeasured_s)
        self.max_age_s = float(max_age_s)
        self._samples: deque[tuple[int, float]] = deque(maxlen=max_samples)
        self.rejected = 0  # NaN or infinite ages (dropped)
        self.clamped = 0  # negative ages (counted as 0) or above max_age_s

    def clear(self) -> None:
        self._samples.clear()

    def __len__(self) -> int:
        return len(self._samples)

    def _clean(self, age_s: float) -> float | None:
        age = float(age_s)
        if not math.isfinite(age):
            self.rejected += 1
            return None
        if age < 0.0 or age > self.max_age_s:
            self.clamped += 1
            return min(max(age, 0.0), self.max_age_s)
        return age

    def add(self, capture_ns: int, data_age_s: float) -> bool:
        """Record the age of frame ``capture_ns``'s data when its command left; False when
        the sample was rejected (NaN or infinite)."""
        age = self._clean(data_age_s)
        if age is None:
            return False
        capture_ns = int(capture_ns)
        if self._samples and capture_ns < self._samples[-1][0]:
            self.clamped += 1  # out of order: kept, stamped as the newest
            capture_ns = self._samples[-1][0]
        self._samples.append((capture_ns, age))
        oldest_ns = capture_ns - round(self.window_s * 1e9)
        while self._samples and self._samples[0][0] < oldest_ns:
            self._samples.popleft()
        return True

    def _sorted(self) -> list[float]:
        return sorted(age for _, age in self._samples)

    def percentile_s(self, q: float | None = None) -> float | None:
        """The ``q`` (default: the budget's) percentile of the window [s], None if empty."""
        ages = self._sorted()
        if not ages:
            return None
        return nearest_rank_percentile(ages, self.percentile if q is None else q)

    def budget_s(self, current_age_s: float | None = None) -> float:
        """The latency ``τ`` to budget now [s] (module docstring); ``current_age_s``: the
        age the frame being processed already has (None: not known)."""
        budget = self.floor_s
        high = self.percentile_s()
        if high is not None:
            budget = max(budget, high + self.unmeasured_s)
        if current_age_s is not None:
            age = self._clean(current_age_s)
            if age is not None:
                budget = max(budget, age + self.unmeasured_s)
        return budget

    def stats(self) -> AgeStats:
        """Median, p99, the budget's percentile and the processing rate of the window."""
        ages = self._sorted()
        n = len(ages)
        rate = None
        if n >= 2:
            span_s = (self._samples[-1][0] - self._samples[0][0]) * 1e-9
            if span_s > 0.0:
                rate = (n - 1) / span_s
        if not ages:
            return AgeStats(0, None, None, None, rate)
        return AgeStats(
            n,
            nearest_rank_percentile(ages, 50.0),
            nearest_rank_percentile(ages, 99.0),
            nearest_rank_percentile(ages, self.percentile),
            rate,
        )
