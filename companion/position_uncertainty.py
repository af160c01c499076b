"""How far the companion widens its margins for the uncertainty of the position estimate.

Issue 31 item 4. The known-space map is registered with the autopilot's position estimate
at each frame's capture time, and the vehicle is flown by the same estimate later. When the
estimate wanders or jumps between seeing and flying (GPS does both), the map's surfaces move
relative to the true vehicle by the change of the estimate's error. The margins along the
path (the safety envelope's ``margin_m``) do not cover a sideways shift: the swept section
is one vehicle radius wide and a boundary is inflated by the vehicle radius and the safety
margin only.

So the vehicle is treated as ``u`` larger wherever its size enters the map: the boundaries
(:mod:`companion.guidance.map_boundaries`), the known-space path's clearance and section
(:mod:`companion.guidance.known_path`) and the envelope's swept section
(:mod:`companion.guidance.envelope`) all grow by ``u`` — the usual inflation of a robot's
footprint by its localisation uncertainty.

``u`` is the larger of what the operator configures (``PerceptionConfig.
position_uncertainty_m``, for an estimate that states nothing) and the horizontal accuracy
the autopilot states for its estimate: GPS_RAW_INT ``h_acc`` [mm], which both ArduPilot
(``AP_GPS::send_mavlink_gps_raw``, from the receiver's horizontal accuracy) and PX4
(``MavlinkStreamGPSRawInt``) send. A stated accuracy beyond what the margins may take
(``PerceptionConfig.max_position_uncertainty_m``) is not covered: the widening stops at
that bound and the companion reports that its margins do not cover the estimate, rather
than flying as if they did.

Pure: numbers in, numbers out; no clock, no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["NO_WIDENING", "Widening", "widening"]

_STEP_M = 0.01  # the widening is rounded up to whole centimetres (maps are rebuilt on change)


@dataclass(frozen=True)
class Widening:
    """The margin widening of one frame.

    Attributes
    ----------
    widen_m : float
        Added to the vehicle's radius wherever it enters the map [m], rounded up to 1 cm.
    stated_m : float or None
        The horizontal accuracy the autopilot stated [m]; None when it stated none.
    covered : bool
        False when the uncertainty wanted exceeds ``max_m``: the margins do not cover it.
    """

    widen_m: float
    stated_m: float | None
    covered: bool


#: nothing stated, nothing configured
NO_WIDENING = Widening(widen_m=0.0, stated_m=None, covered=True)


def widening(stated_m: float | None, floor_m: float, max_m: float) -> Widening:
    """The widening for a stated horizontal accuracy ``stated_m`` [m] (None or not finite:
    not stated), with the configured least uncertainty ``floor_m`` and the most the margins
    may take ``max_m`` [m]."""
    if stated_m is not None and not (math.isfinite(stated_m) and stated_m >= 0.0):
        stated_m = None
    wanted = max(floor_m, 0.0 if stated_m is None else stated_m)
    widen = min(wanted, max_m)
    return Widening(
        widen_m=math.ceil(widen / _STEP_M - 1e-9) * _STEP_M,
        stated_m=stated_m,
        covered=wanted <= max_m,
    )
