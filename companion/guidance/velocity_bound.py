"""Step 9 of the safety envelope: the room along the way the vehicle moves (issue 36 item 5).

Steps 1–5 of :mod:`companion.guidance.envelope` measure the known-free distance ``F``
along the *path* ``u`` and bound the carrot and the speed by it. The vehicle does not
always move along ``u``: after a turn of the path, an avoidance or a gust its velocity
can point tens of degrees off it, outside the camera's ±24° view, where little was seen
free (facing_away-304, stereo, traced per frame: velocity bearing 60–99° against a path
at 55° and a heading of 52–70°; free along the velocity 8 m → 1.0 m while ``F`` stayed
4–5 m, so the limit stayed 5.26 m/s and 20 frames flew over it). A stop begins along the
velocity: the autopilot keeps its motion for the latency ``τ`` and its braking (or its
turn toward the carrot, ArduCopter's ``shape_pos_vel_accel``) only then removes it. So
invariant 2's stop must fit the known-free distance along the velocity too:

* ``F_v``, the known-free distance of the vehicle's section along the velocity (the
  direction a braking bound is stated along,
  :func:`~companion.guidance.envelope_direction.brake_direction`: a staged climb's
  slack above the path is not counted against it), measured as steps 5 and 8 measure
  the way the vehicle already moves (the near field's unseen rim excused);
* when steps 5 and 8 did not brake and the stop no longer fits it
  (``d_stop + margin > F_v``, :func:`stop_fits`), that frame brakes as step 5 does:
  the carrot at the vehicle, the bound stated along the velocity without the margin
  (the brake's reserve), so the stated limit and the carrot drop in the frame the room
  along the velocity does.

While the stop fits, the path's carrot and limit stand: the carrot *on the path* pulls
the velocity back toward space seen free (the turn makes ``F_v`` grow again), and a
carrot more than 15° off the velocity is step 8's to certify along the path the autopilot
flies to it. Stating the velocity's smaller limit there as well was tried: it changed
step 8's prediction (a lower speed cap turns tighter) and braked certified turns away
from an obstacle (``tests/test_envelope_momentum.py``). A brake never freezes the
vehicle: below :data:`MIN_SPEED_MPS` there is no direction of motion and ``F_v`` is not
counted (a vehicle at rest moves off along ``u``, where ``F_v = F``).

Pure: the map is a query function of a unit direction; no clock, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from companion.guidance.envelope_direction import brake_direction

__all__ = ["MIN_SPEED_MPS", "stop_fits", "velocity_room_m"]

MIN_SPEED_MPS = 0.1
"""Below this speed [m/s] the vehicle has no direction of motion: ``F_v`` is not counted
(the envelope's own threshold for a braking bound)."""


def velocity_room_m(
    vel_ned_mps: np.ndarray, max_elev_rad: float, free_along: Callable[[np.ndarray], float]
) -> float:
    """Known-free distance along the way the vehicle moves [m]; ``inf`` below
    :data:`MIN_SPEED_MPS` (no direction, nothing to bound).

    Parameters
    ----------
    vel_ned_mps : ndarray, shape (3,)
        The vehicle's velocity [m/s, NED].
    max_elev_rad : float
        The path's elevation limit [rad] (:func:`~companion.guidance.envelope_direction.
        brake_direction`'s climb slack).
    free_along : callable
        ``unit_dir_ned -> metres`` of known-free travel for the vehicle's section from its
        position (the envelope's query, near field excused as for a brake).
    """
    speed = math.sqrt(float(vel_ned_mps @ vel_ned_mps))
    if not speed >= MIN_SPEED_MPS:  # also NaN
        return math.inf
    return float(free_along(brake_direction(vel_ned_mps, max_elev_rad)))


def stop_fits(stopping_distance_m: float, margin_m: float, free_v_m: float) -> bool:
    """The stop (``d_stop``) and the margin fit the room along the velocity ``F_v``
    (``inf`` when not moving: always)."""
    return stopping_distance_m + margin_m <= free_v_m
