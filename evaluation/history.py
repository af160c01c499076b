"""Time history of a run: fixed named columns, appended per sample, written as CSV."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

__all__ = ["COLUMNS", "History"]

#: Column names, NED/FRD and MAVLink angle conventions, units in the names.
COLUMNS: tuple[str, ...] = (
    "time_s",
    "north_m",
    "east_m",
    "down_m",
    "vn_mps",
    "ve_mps",
    "vd_mps",
    "roll_deg",
    "pitch_deg",
    "yaw_deg",
    "roll_cmd_deg",
    "pitch_cmd_deg",
    "yaw_cmd_deg",
    "rotor1_n",
    "rotor2_n",
    "rotor3_n",
    "rotor4_n",
    "nearest_surface_m",
    "avoid_flag",
    "mode",
    "setpoint_north_m",
    "setpoint_east_m",
    "setpoint_down_m",
    "n_obstacles_seen",
    "tilt_saturated",
    "free_distance_m",
    "speed_limit_mps",
    "speed_mps",
)


class History:
    """Append-only table of :data:`COLUMNS`; cheap appends, numpy views on demand."""

    def __init__(self) -> None:
        self._rows: list[tuple[float, ...]] = []
        # OBSTACLE_DISTANCE sectors the companion would send at the closest approach
        # (companion.proximity.sectors.ProximitySectors) and that approach's surface
        # distance [m]; None until a frame was recorded. The sectors are computed once the
        # approach stops getting nearer (settle_proximity), not on every nearer frame.
        self._proximity_at_closest = None
        self._pending_sectors = None
        self.proximity_surface_m = math.inf

    @property
    def proximity_at_closest(self):
        """The sectors at the closest approach noted (None before any)."""
        self.settle_proximity(math.inf)
        return self._proximity_at_closest

    def note_proximity(self, surface_m: float, sectors_fn) -> None:
        """Keep ``sectors_fn`` when ``surface_m`` is the closest approach so far.

        ``sectors_fn`` reads the map as it is now: it is called by :meth:`settle_proximity`
        (or when :attr:`proximity_at_closest` is read), which must come before the map
        changes.
        """
        if surface_m < self.proximity_surface_m:
            self.proximity_surface_m = surface_m
            self._pending_sectors = sectors_fn

    def settle_proximity(self, next_surface_m: float) -> None:
        """Before the map changes for a frame at ``next_surface_m`` [m]: compute the kept
        candidate's sectors now, unless that frame is nearer and will replace it."""
        if self._pending_sectors is not None and next_surface_m >= self.proximity_surface_m:
            self._proximity_at_closest = self._pending_sectors()
            self._pending_sectors = None

    def append(self, **values: float) -> None:
        """Add one sample; every column must be given, nothing else."""
        missing = [c for c in COLUMNS if c not in values]
        extra = [k for k in values if k not in COLUMNS]
        if missing or extra:
            raise KeyError(f"History.append: missing {missing}, unknown {extra}")
        self._rows.append(tuple(float(values[c]) for c in COLUMNS))

    def __len__(self) -> int:
        return len(self._rows)

    def column(self, name: str) -> np.ndarray:
        """One column as a float array."""
        i = COLUMNS.index(name)
        return np.fromiter((r[i] for r in self._rows), dtype=float, count=len(self._rows))

    def write_csv(self, path: Path) -> None:
        """Write all samples with a header row."""
        with Path(path).open("w", newline="") as fh:
            writer = csv.writer(fh)
            writer.writerow(COLUMNS)
            writer.writerows(self._rows)
