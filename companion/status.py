"""The companion's status on Zenoh: one JSON document per processed frame.

Key ``stereo_avoid/<vehicle_id>/companion/status`` (:func:`protocols.keys.companion_status_key`).
``obstacles`` is the one obstacle model guidance steers on, the envelope bounds by and
OBSTACLE_DISTANCE reports: the known-space map's pieces within the detection range, each a
collision safety boundary (:attr:`companion.pipeline.PipelineOutput.obstacles`,
:mod:`companion.guidance.map_boundaries`), with its stable ``key`` and ``range_m`` from
the vehicle to its nearest voxel.
:func:`status_document` is pure; :class:`StatusPublisher` puts it on the wire.

Schema versions (``schema``): 1 (no ``schema`` key) had perception's per-frame spheres in
``obstacles``; 2 has the map's boundaries there, with the same keys plus ``key``.
``boundaries`` (the same spheres without ``range_m``) is kept for version-1 readers.

Document (NED, SI units; latencies in ms of the host's monotonic clock)::

    {"sequence": 12, "capture_ns": 400000000, "state": "active", "phase": "active",
     "autopilot_mode": "GUIDED", "mode": "avoid", "reason": "critical", "avoidance_flag": true,
     "setpoint_ned_m": [..], "yaw_rad": .., "aiming_point_ned_m": [..] | null,
     "schema": 2, "obstacles": [{"center_ned_m": [..], "radius_m": .., "range_m": .., "key": ..}],
     "boundaries": [{"center_ned_m": [..], "radius_m": .., "key": ..}],
     "pos_ned_m": [..], "pose": "ok", "health": "healthy", "waypoint": 0,
     "latency_ms": {"receive_to_send": .., "compute": ..}, "counters": {...}}
"""

from __future__ import annotations

import json
import logging
from typing import Any

import zenoh

from companion.pipeline import PipelineOutput

__all__ = ["STATUS_SCHEMA", "StatusPublisher", "status_document"]

#: the status document's schema version (module docstring)
STATUS_SCHEMA = 2

_log = logging.getLogger("companion.status")


def _vec(v) -> list[float] | None:
    return None if v is None else [round(float(x), 4) for x in v]


def status_document(out: PipelineOutput, **extra: Any) -> dict[str, Any]:
    """JSON-ready status of one frame's pipeline output plus ``extra`` fields."""
    g = out.guidance
    doc: dict[str, Any] = {
        "schema": STATUS_SCHEMA,
        "sequence": out.perception.sequence,
        "capture_ns": out.perception.capture_ns,
        "mode": g.mode.value,
        "reason": g.reason.value,
        "avoidance_flag": bool(g.avoidance_flag),
        "setpoint_ned_m": _vec(out.setpoint_ned_m),
        "guidance_setpoint_ned_m": _vec(g.setpoint_ned_m),
        "envelope": {
            "free_distance_m": round(float(out.envelope.free_distance_m), 3),
            "stopping_distance_m": round(float(out.envelope.stopping_distance_m), 3),
            "speed_limit_mps": round(float(out.envelope.speed_limit_mps), 3),
            "speed_mps": round(float(out.envelope.speed_mps), 3),
            "limited": bool(out.envelope.limited),
            "overspeed": bool(out.envelope.overspeed),
        },
        "yaw_rad": round(float(g.yaw_rad), 5),
        "aiming_point_ned_m": _vec(g.aiming_point_ned_m),
        "obstacles": [
            {
                "center_ned_m": _vec(o.center_ned_m),
                "radius_m": round(float(o.radius_m), 4),
                "range_m": round(float(o.nearest_m), 4),
                "key": int(o.track_key),
            }
            for o in out.obstacles
        ],
        "boundaries": [
            {
                "center_ned_m": _vec(b.center_ned_m),
                "radius_m": round(float(b.radius_m), 4),
                "key": int(b.track_key),
            }
            for b in out.boundaries
        ],
    }
    doc.update(extra)
    return doc


class StatusPublisher:
    """Publishes status documents on ``key`` (drops under congestion, never blocks)."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self.key = key
        self._session = session
        self._pub = None
        self.published = 0
        self.errors = 0

    def open(self) -> None:
        self._pub = self._session.declare_publisher(
            self.key, congestion_control=zenoh.CongestionControl.DROP
        )

    def publish(self, doc: dict[str, Any]) -> None:
        if self._pub is None:
            return
        try:
            self._pub.put(json.dumps(doc, separators=(",", ":")))
        except (zenoh.ZError, TypeError, ValueError) as exc:
            self.errors += 1
            _log.debug("status not published: %s", exc)
            return
        self.published += 1

    def close(self) -> None:
        if self._pub is not None:
            self._pub.undeclare()
            self._pub = None
