"""Guidance's modes and the reasons for them (paper Fig. 5: navigation and avoidance
maneuvers; the holds this project adds), shared by the step and its phases."""

from __future__ import annotations

from enum import Enum

__all__ = ["Mode", "Reason"]


class Mode(Enum):
    """What the vehicle is doing."""

    NAVIGATE = "navigate"
    """Waypoint guidance to the goal (paper Fig. 5, navigation maneuver)."""
    AVOID = "avoid"
    """Guidance to the aiming point (or out of a boundary sphere)."""
    HOLD = "hold"
    """Brake and hold position: no safe direction, or the goal is unreachable."""


class Reason(Enum):
    """Why the mode is what it is (for status messages, logs and failure statistics)."""

    NO_THREAT = "no_threat"
    CRITICAL = "critical"
    HYSTERESIS = "hysteresis"
    GOAL_BLOCKED = "goal_blocked"
    INSIDE_BOUNDARY = "inside_boundary"
    NO_FREE_DIRECTION = "no_free_direction"
    GOAL_UNREACHABLE = "goal_unreachable"
    """The goal lies inside a confirmed boundary: holding at the stop point outside it."""
    NO_PROGRESS = "no_progress"
    """No progress toward the goal for ``stall_timeout_s``: holding where it is."""
    KNOWN_PATH = "known_path"
    """Flying the first leg of a path through space seen free: the cone rule left no
    admissible direction or closed a way the map shows open."""
