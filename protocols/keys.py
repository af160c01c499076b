"""Zenoh key expressions shared by plant_sim and the companion (DESIGN.md "Wire protocols")."""

from __future__ import annotations

import re

__all__ = [
    "ALL_STEREO_KEYS",
    "ROOT",
    "companion_status_key",
    "stereo_key",
    "validate_vehicle_id",
    "vehicle_of_stereo_key",
]

#: First chunk of every key expression of the project.
ROOT = "stereo_avoid"
#: Stereo frames of every vehicle (diagnostics: which vehicle ids are publishing)
ALL_STEREO_KEYS = f"{ROOT}/*/stereo"

_VEHICLE_ID = re.compile(r"^[A-Za-z0-9_\-]+$")


def validate_vehicle_id(vehicle_id: str) -> str:
    """Return ``vehicle_id`` if it is one plain key chunk (letters, digits, ``_``, ``-``).

    Raises
    ------
    ValueError
        If it is empty or contains ``/``, wildcards or other characters Zenoh treats
        specially.
    """
    if not isinstance(vehicle_id, str) or not _VEHICLE_ID.match(vehicle_id):
        raise ValueError(
            f"vehicle_id must be letters, digits, '_' or '-' (one key chunk), got {vehicle_id!r}"
        )
    return vehicle_id


def stereo_key(vehicle_id: str) -> str:
    """Key of the stereo frames of ``vehicle_id``: ``stereo_avoid/<vehicle_id>/stereo``."""
    return f"{ROOT}/{validate_vehicle_id(vehicle_id)}/stereo"


def companion_status_key(vehicle_id: str) -> str:
    """Key of the companion's status: ``stereo_avoid/<vehicle_id>/companion/status``."""
    return f"{ROOT}/{validate_vehicle_id(vehicle_id)}/companion/status"


def vehicle_of_stereo_key(key: str) -> str | None:
    """The vehicle id of a stereo-frame key (``stereo_avoid/<id>/stereo``), else None."""
    parts = str(key).split("/")
    if (
        len(parts) == 3
        and parts[0] == ROOT
        and parts[2] == "stereo"
        and _VEHICLE_ID.match(parts[1])
    ):
        return parts[1]
    return None
