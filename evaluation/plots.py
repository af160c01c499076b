"""Figures of a run that correspond to the paper's Fig. 6–11 (PNG files).

Uses matplotlib's object API (``Figure``), not pyplot: no global backend or state.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Circle, Rectangle

from evaluation.history import History
from plant_sim.world import World

__all__ = ["write_figures"]


def write_figures(
    history: History,
    world: World,
    goal_ned_m: Sequence[float],
    out_dir: Path,
    *,
    max_tilt_deg: float,
    rotor_limits_n: tuple[float, float],
    detect_threshold_m: float,
) -> list[Path]:
    """Write fig6_trajectory.png … fig11_avoid_flag.png into ``out_dir``; return the paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    figures = {
        "fig6_trajectory.png": _trajectory(history, world, goal_ned_m),
        "fig7_attitude.png": _attitude(history, max_tilt_deg),
        "fig8_velocity.png": _velocity(history),
        "fig9_rotor_thrust.png": _rotor_thrust(history, rotor_limits_n),
        "fig10_distance.png": _distance(history, detect_threshold_m),
        "fig11_avoid_flag.png": _avoid_flag(history),
    }
    paths = []
    for name, fig in figures.items():
        fig.tight_layout()
        path = out_dir / name
        fig.savefig(path, dpi=110)
        paths.append(path)
    return paths


def _trajectory(history: History, world: World, goal_ned_m: Sequence[float]) -> Figure:
    """Fig. 6: trajectory, top view (east right, north up) and side view."""
    north, east, down = (history.column(c) for c in ("north_m", "east_m", "down_m"))
    fig = Figure(figsize=(11, 4.8))
    top, side = fig.subplots(1, 2)
    top.plot(east, north, "b-", label="vehicle")
    top.plot(east[0], north[0], "go", label="start")
    top.plot(goal_ned_m[1], goal_ned_m[0], "r*", ms=12, label="goal")
    for patch in _obstacle_patches(world, top_view=True):
        top.add_patch(patch)
    top.set(xlabel="east [m]", ylabel="north [m]", title="Fig. 6 trajectory (top view)")
    top.set_aspect("equal", adjustable="datalim")
    top.legend(loc="best", fontsize=8)
    top.grid(True, alpha=0.3)
    side.plot(north, -down, "b-")
    for patch in _obstacle_patches(world, top_view=False):
        side.add_patch(patch)
    side.set(xlabel="north [m]", ylabel="altitude [m]", title="side view")
    side.set_aspect("equal", adjustable="datalim")
    side.grid(True, alpha=0.3)
    return fig


def _attitude(history: History, max_tilt_deg: float) -> Figure:
    """Fig. 7: attitude, commanded (dotted) vs actual (solid)."""
    t = history.column("time_s")
    fig = Figure(figsize=(9, 7))
    axes = fig.subplots(3, 1, sharex=True)
    for ax, name in zip(axes, ("roll", "pitch", "yaw"), strict=True):
        actual, command = history.column(f"{name}_deg"), history.column(f"{name}_cmd_deg")
        if name == "yaw":  # continuous through ±180°
            actual = np.degrees(np.unwrap(np.radians(actual)))
            command = np.degrees(np.unwrap(np.radians(command), period=2 * np.pi))
            command += 360.0 * np.round((actual - command) / 360.0)
        ax.plot(t[1:], actual[1:], "b-", label="actual")
        ax.plot(t[1:], command[1:], "r:", label="command")  # t=0: no command yet
        if name != "yaw":
            for sign in (-1, 1):
                ax.axhline(sign * max_tilt_deg, color="k", lw=0.6, ls="--")
        ax.set_ylabel(f"{name} [deg]")
        ax.grid(True, alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[0].set_title("Fig. 7 attitude (MAVLink roll/pitch/yaw, NED)")
    axes[-1].set_xlabel("time [s]")
    return fig


def _velocity(history: History) -> Figure:
    """Fig. 8: velocity, NED."""
    t = history.column("time_s")
    fig = Figure(figsize=(9, 4))
    ax = fig.subplots()
    for name, style in (("vn", "b-"), ("ve", "g-"), ("vd", "r-")):
        ax.plot(t, history.column(f"{name}_mps"), style, label=name)
    ax.set(xlabel="time [s]", ylabel="velocity [m/s]", title="Fig. 8 velocity (NED)")
    ax.legend(fontsize=8)
    ax.grid(True, alpha=0.3)
    return fig


def _rotor_thrust(history: History, rotor_limits_n: tuple[float, float]) -> Figure:
    """Fig. 9: rotor thrusts and their limits."""
    t = history.column("time_s")
    fig = Figure(figsize=(9, 4))
    ax = fig.subplots()
    for i in range(1, 5):
        ax.plot(t, history.column(f"rotor{i}_n"), label=f"F{i}")
    for lim in rotor_limits_n:
        ax.axhline(lim, color="k", lw=0.6, ls="--")
    ax.set(xlabel="time [s]", ylabel="thrust [N]", title="Fig. 9 rotor thrusts")
    ax.legend(fontsize=8)
    ax.grid(True, alpha=0.3)
    return fig


def _distance(history: History, detect_threshold_m: float) -> Figure:
    """Fig. 10: distance from the vehicle centre to the nearest obstacle surface."""
    t = history.column("time_s")
    dist = history.column("nearest_surface_m")
    fig = Figure(figsize=(9, 4))
    ax = fig.subplots()
    ax.plot(t, dist, "b-", label="vehicle centre to nearest surface")
    ax.axhline(detect_threshold_m, color="g", ls="--", lw=0.8, label="detection threshold")
    ax.axhline(0.0, color="r", lw=0.8)
    finite = dist[[math.isfinite(d) for d in dist]]
    if finite.size:
        ax.set_ylim(min(0.0, finite.min()) - 0.2, min(finite.max(), 25.0) + 0.5)
    ax.set(xlabel="time [s]", ylabel="distance [m]", title="Fig. 10 distance from obstacle")
    ax.legend(fontsize=8)
    ax.grid(True, alpha=0.3)
    return fig


def _avoid_flag(history: History) -> Figure:
    """Fig. 11: the avoidance flag."""
    fig = Figure(figsize=(9, 2.8))
    ax = fig.subplots()
    ax.step(history.column("time_s"), history.column("avoid_flag"), "b-", where="post")
    ax.set(
        xlabel="time [s]", ylabel="flag", title="Fig. 11 collision avoidance flag", ylim=(-0.1, 1.1)
    )
    ax.grid(True, alpha=0.3)
    return fig


def _obstacle_patches(world: World, top_view: bool) -> list:
    """Every obstacle's outline in the top view (x east, y north) or the side view
    (x north, y altitude): spheres as circles, boxes as rectangles, vertical cylinders as
    circles from above and rectangles from the side."""
    style = {"color": "0.4", "alpha": 0.6}
    patches = []
    for s in world.spheres:
        n, e, d = s.center_ned_m
        patches.append(Circle((e, n) if top_view else (n, -d), s.radius_m, **style))
    for b in world.boxes:
        (n, e, d), (sn, se, sd) = b.center_ned_m, b.size_m
        if top_view:
            patches.append(Rectangle((e - se / 2, n - sn / 2), se, sn, **style))
        else:
            patches.append(Rectangle((n - sn / 2, -d - sd / 2), sn, sd, **style))
    for c in world.cylinders:
        n, e, d = c.center_ned_m
        if top_view:
            patches.append(Circle((e, n), c.radius_m, **style))
        else:
            r, h = c.radius_m, c.height_m
            patches.append(Rectangle((n - r, -d - h / 2), 2 * r, h, **style))
    return patches
