"""Ground-truth time history of a run (CSV): pose, obstacle clearance, controller saturation.

One row per sample of simulation time. Columns (NED/FRD, SI units, MAVLink 3-2-1 angles)::

    time_s, pos_n_m, pos_e_m, pos_d_m, vel_n_mps, vel_e_mps, vel_d_mps,
    roll_rad, pitch_rad, yaw_rad, roll_cmd_rad, pitch_cmd_rad, yaw_cmd_rad,
    tilt_saturated, rotor_saturated, on_ground, armed, mode,
    nearest_obstacle, surface_distance_m, clearance_m,
    rotor1_n, rotor2_n, rotor3_n, rotor4_n

``nearest_obstacle`` indexes ``World.obstacles`` (spheres, then boxes, then cylinders);
``surface_distance_m`` is the distance from the vehicle's centre to the nearest obstacle
surface of any shape (negative inside); ``clearance_m`` subtracts the vehicle radius (a
collision when < 0); both empty without obstacles. Verdicts read this file, never telemetry.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

from plant_sim.vehicle import VehicleState
from plant_sim.world import World

__all__ = ["COLUMNS", "TruthLogWriter", "nearest_surface"]

COLUMNS = (
    "time_s",
    "pos_n_m",
    "pos_e_m",
    "pos_d_m",
    "vel_n_mps",
    "vel_e_mps",
    "vel_d_mps",
    "roll_rad",
    "pitch_rad",
    "yaw_rad",
    "roll_cmd_rad",
    "pitch_cmd_rad",
    "yaw_cmd_rad",
    "tilt_saturated",
    "rotor_saturated",
    "on_ground",
    "armed",
    "mode",
    "nearest_obstacle",
    "surface_distance_m",
    "clearance_m",
    "rotor1_n",
    "rotor2_n",
    "rotor3_n",
    "rotor4_n",
)


def nearest_surface(world: World, pos_ned_m) -> tuple[int, float]:
    """(index into ``world.obstacles``, distance [m]) of the nearest obstacle surface, of any
    shape (spheres, boxes, cylinders; negative inside); (-1, inf) without obstacles."""
    return world.nearest_obstacle(pos_ned_m)


class TruthLogWriter:
    """Writes :data:`COLUMNS` rows; :meth:`close` flushes. Tracks the minimum clearance."""

    def __init__(self, path: str | Path, world: World, body_radius_m: float) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, "w", newline="")  # noqa: SIM115 (closed in close())
        self._writer = csv.writer(self._file)
        self._writer.writerow(COLUMNS)
        self._world = world
        self._body_radius_m = body_radius_m
        self.rows = 0
        self.min_clearance_m = math.inf

    def write(self, s: VehicleState, mode_name: str) -> None:
        """One row from plant-sim's own physics."""
        self._row(
            s.time_s,
            s.pos_ned_m,
            s.vel_ned_mps,
            (s.roll_rad, s.pitch_rad, s.yaw_rad),
            (s.roll_cmd_rad, s.pitch_cmd_rad, s.yaw_cmd_rad),
            tilt_saturated=int(s.tilt_saturated),
            rotor_saturated=int(s.rotor_saturated),
            on_ground=int(s.on_ground),
            armed=int(s.armed),
            mode_name=mode_name,
            rotor_thrusts_n=s.rotor_thrusts_n,
        )

    def write_external(
        self,
        time_s: float,
        pos_ned_m,
        vel_ned_mps,
        rpy_rad: tuple[float, float, float],
        rpy_cmd_rad: tuple[float, float, float] | None,
        *,
        on_ground: bool | None,
        armed: bool | None,
        mode_name: str,
    ) -> None:
        """One row from an external autopilot's telemetry (camera-only mode).

        What the telemetry does not tell (commanded attitude when the autopilot sends no
        ATTITUDE_TARGET, saturation flags, rotor thrusts) is left empty, never invented.
        """
        self._row(
            time_s,
            pos_ned_m,
            vel_ned_mps,
            rpy_rad,
            rpy_cmd_rad,
            tilt_saturated="",
            rotor_saturated="",
            on_ground="" if on_ground is None else int(on_ground),
            armed="" if armed is None else int(armed),
            mode_name=mode_name,
            rotor_thrusts_n=None,
        )

    def _row(
        self,
        time_s: float,
        p,
        v,
        rpy_rad,
        rpy_cmd_rad,
        *,
        tilt_saturated,
        rotor_saturated,
        on_ground,
        armed,
        mode_name: str,
        rotor_thrusts_n,
    ) -> None:
        idx, dist = nearest_surface(self._world, p)
        clearance = dist - self._body_radius_m
        if idx >= 0:
            self.min_clearance_m = min(self.min_clearance_m, clearance)
        cmd = ("", "", "") if rpy_cmd_rad is None else tuple(f"{a:.5f}" for a in rpy_cmd_rad)
        thrusts = (
            ("", "", "", "")
            if rotor_thrusts_n is None
            else (tuple(f"{f:.4f}" for f in rotor_thrusts_n))
        )
        self._writer.writerow(
            (
                f"{time_s:.4f}",
                f"{p[0]:.4f}",
                f"{p[1]:.4f}",
                f"{p[2]:.4f}",
                f"{v[0]:.4f}",
                f"{v[1]:.4f}",
                f"{v[2]:.4f}",
                *(f"{a:.5f}" for a in rpy_rad),
                *cmd,
                tilt_saturated,
                rotor_saturated,
                on_ground,
                armed,
                mode_name,
                idx if idx >= 0 else "",
                f"{dist:.4f}" if idx >= 0 else "",
                f"{clearance:.4f}" if idx >= 0 else "",
                *thrusts,
            )
        )
        self.rows += 1

    def flush(self) -> None:
        if not self._file.closed:
            self._file.flush()

    def close(self) -> None:
        if not self._file.closed:
            self._file.close()
