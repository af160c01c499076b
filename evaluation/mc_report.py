"""The end of a Monte Carlo batch: a summary table and figures in the output folder.

Writes ``summary.txt`` (the table printed on the console), ``summary.json`` (the numbers,
with every verdict), ``min_separation_hist.png`` (minimum distance from the vehicle
centre to an obstacle surface, the collision distance marked), ``failures_by_cause.png``
and ``failing_scenes.png`` (plan view of every scene that did not reach its goal, up to
24, coloured by cause, with the seed to replay), and ``family_<name>.png`` per scene family
in the batch (outcomes, a reported stop by its reason, and the time to goal of the scenes
that reached it). matplotlib's object API (``Figure``), no pyplot: no global backend or
state.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Circle, Rectangle

from evaluation.harness import Verdict
from evaluation.montecarlo import scene_of

__all__ = ["format_summary", "write_report"]

_MAX_MAP_SCENES = 24
_CAUSE_COLOURS = {
    "collision": "tab:red",
    "hold": "tab:blue",
    "timeout": "tab:orange",
    "error": "tab:purple",
    "goal not reached": "tab:gray",
}


def format_summary(summary: dict[str, Any], *, family: str, perception: str) -> str:
    """The summary as a text table (what ``stereo-avoid montecarlo`` prints)."""
    n = summary["runs"]
    sep = summary["min_separation_m"]
    fams = "  ".join(f"{k} {v['safe']}/{v['runs']}" for k, v in summary["by_family"].items())
    other = n - summary["goal_reached"] - summary["safe_stops"] - summary["collisions"]
    lines = [
        f"scenes               {n} ({family}, {perception} perception)",
        f"goal reached         {summary['goal_reached']} ({summary['goal_reached_rate']:.1%})",
        f"safe reported stop   {summary['safe_stops']}",
        f"collisions           {summary['collisions']}",
        f"other (timeout, ...) {other}",
        f"safe outcome rate    {summary['safe_outcome_rate']:.2%} (goal or reported stop)",
        f"safe by family       {fams}",
        "min separation [m]   "
        f"min {sep['min']:.2f}  p5 {sep['p5']:.2f}  median {sep['median']:.2f}",
        f"avoidance time [s]   mean {summary['avoidance_time_s']['mean']:.2f}",
        f"failures by cause    {summary['failures_by_cause'] or 'none'}",
    ]
    if summary["collision_seeds"]:
        lines.append(f"collision seeds      {summary['collision_seeds']}")
    if summary["unsafe_seeds"]:
        lines.append(
            f"unsafe seeds         {summary['unsafe_seeds'][:20]}"
            + (" ..." if len(summary["unsafe_seeds"]) > 20 else "")
        )
        lines.append(
            f"replay one           stereo-avoid replay {summary['unsafe_seeds'][0]} "
            f"--family {family} --perception {perception}"
        )
    return "\n".join(lines)


def write_report(
    out_dir: Path,
    verdicts: list[Verdict],
    summary: dict[str, Any],
    *,
    family: str,
    perception: str,
    throughput: dict[str, float] | None = None,
    code_counts: dict[str, int] | None = None,
) -> str:
    """Write the table and the figures to ``out_dir``; returns the table. ``code_counts``:
    seeds per code fingerprint (:mod:`evaluation.mc_provenance`), a line of the
    table (flagged when the batch mixes code)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    table = format_summary(summary, family=family, perception=perception)
    if throughput:
        table += (
            f"\nthroughput           {throughput['scenes_per_min']:.1f} scenes/min "
            f"({throughput['scenes']} scenes in {throughput['wall_s']:.0f} s this session)"
        )
    if code_counts:
        flown = ", ".join(f"{c} ({n} seeds)" for c, n in code_counts.items())
        mixed = "MIXED CODE: " if len(code_counts) > 1 else ""
        table += f"\ncode                 {mixed}{flown}"
    (out_dir / "summary.txt").write_text(table + "\n")
    doc = {
        **summary,
        "family": family,
        "perception": perception,
        "throughput": throughput,
        "code": code_counts,
    }
    (out_dir / "summary.json").write_text(json.dumps(doc, indent=2, allow_nan=True) + "\n")
    _separation_histogram(out_dir / "min_separation_hist.png", verdicts, perception)
    _failures_by_cause(out_dir / "failures_by_cause.png", summary, perception)
    _failing_scenes(out_dir / "failing_scenes.png", verdicts, family)
    for name, members in _by_family(verdicts).items():
        _family_figure(out_dir / f"family_{name}.png", name, members, perception)
    return table


def _by_family(verdicts: list[Verdict]) -> dict[str, list[Verdict]]:
    """Verdicts by the family in their scene's name (``gap-12`` → ``gap``)."""
    out: dict[str, list[Verdict]] = {}
    for v in verdicts:
        out.setdefault(v.scene.rsplit("-", 1)[0], []).append(v)
    return dict(sorted(out.items()))


def _outcome(v: Verdict) -> str:
    if v.collided:
        return "collision"
    if v.passed:
        return "goal"
    if v.failure == "hold":
        return f"stop: {v.hold_reason}"
    return v.failure or "goal not reached"


def _family_figure(path: Path, name: str, verdicts: list[Verdict], perception: str) -> None:
    """Outcomes (a reported stop by its reason) and time to goal of one family."""
    outcomes: dict[str, int] = {}
    for v in verdicts:
        outcomes[_outcome(v)] = outcomes.get(_outcome(v), 0) + 1
    names = sorted(outcomes, key=lambda k: (k != "goal", k))
    fig = Figure(figsize=(10, 4))
    ax_out, ax_time = fig.subplots(1, 2)
    colours = [
        "tab:green" if k == "goal" else _CAUSE_COLOURS.get(k.split(":")[0], "tab:blue")
        for k in names
    ]
    bars = ax_out.bar(names, [outcomes[k] for k in names], color=colours)
    ax_out.bar_label(bars)
    ax_out.tick_params(axis="x", labelsize=7, rotation=20)
    ax_out.set_ylabel("scenes")
    ax_out.set_title(f"{name}: outcomes of {len(verdicts)} scenes ({perception})", fontsize=9)
    times = np.array([v.sim_time_s for v in verdicts if v.passed])
    if times.size:
        ax_time.hist(times, bins=min(20, max(5, times.size)), color="tab:green", alpha=0.8)
        ax_time.axvline(float(np.median(times)), color="k", ls="--", label="median")
        ax_time.legend()
    ax_time.set_xlabel("time to goal [s, simulation]")
    ax_time.set_ylabel("scenes")
    ax_time.set_title(f"{name}: time to goal, {times.size} scenes reached it", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def _separation_histogram(path: Path, verdicts: list[Verdict], perception: str) -> None:
    sep = np.array([v.min_surface_distance_m for v in verdicts], dtype=float)
    sep = sep[np.isfinite(sep)]
    fig = Figure(figsize=(7, 4))
    ax = fig.subplots()
    if sep.size:
        ax.hist(sep, bins=min(60, max(10, sep.size // 10)), color="tab:blue", alpha=0.8)
    ax.axvline(0.25, color="tab:red", ls="--", label="collision distance 0.25 m")
    ax.set_xlabel("minimum distance, vehicle centre to obstacle surface [m]")
    ax.set_ylabel("scenes")
    ax.set_title(f"Minimum separation, {len(verdicts)} scenes ({perception} perception)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def _failures_by_cause(path: Path, summary: dict[str, Any], perception: str) -> None:
    n = summary["runs"]
    outcomes = {
        "goal": summary["goal_reached"],
        **{k: v for k, v in sorted(summary["failures_by_cause"].items())},
    }
    fig = Figure(figsize=(7, 4))
    ax = fig.subplots()
    names = list(outcomes)
    bars = ax.bar(
        names,
        [outcomes[k] for k in names],
        color=["tab:green" if k == "goal" else _CAUSE_COLOURS.get(k, "tab:gray") for k in names],
    )
    ax.bar_label(bars)
    ax.set_ylabel("scenes")
    ax.set_title(f"Outcomes of {n} scenes ({perception} perception; hold = reported stop)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def _failing_scenes(path: Path, verdicts: list[Verdict], family: str) -> None:
    failing = [v for v in verdicts if not v.passed]
    # collisions first, then the other causes, in seed order
    failing.sort(key=lambda v: (not v.collided, v.failure or "", v.seed))
    shown = failing[:_MAX_MAP_SCENES]
    if not shown:
        fig = Figure(figsize=(5, 2))
        ax = fig.subplots()
        ax.axis("off")
        ax.text(0.5, 0.5, f"no failing scene in {len(verdicts)}", ha="center", va="center")
        fig.savefig(path, dpi=100)
        return
    cols = min(6, len(shown))
    rows = math.ceil(len(shown) / cols)
    fig = Figure(figsize=(2.6 * cols, 2.8 * rows))
    axes = fig.subplots(rows, cols, squeeze=False)
    for ax in axes.flat[len(shown) :]:
        ax.axis("off")
    for ax, verdict in zip(axes.flat, shown, strict=False):
        cause = "collision" if verdict.collided else (verdict.failure or "goal not reached")
        colour = _CAUSE_COLOURS.get(cause, "tab:gray")
        try:
            scene = scene_of(verdict.seed, family)
        except (RuntimeError, ValueError):
            ax.set_title(f"seed {verdict.seed}: {cause}", fontsize=8, color=colour)
            continue
        # plan view, east to the right and north up
        for s in scene.world.spheres:
            ax.add_patch(
                Circle((s.center_ned_m[1], s.center_ned_m[0]), s.radius_m, color=colour, alpha=0.35)
            )
        for b in scene.world.boxes:
            (bn, be, _), (ln, le, _) = b.center_ned_m, b.size_m
            ax.add_patch(
                Rectangle((be - 0.5 * le, bn - 0.5 * ln), le, ln, color=colour, alpha=0.35)
            )
        (sn, se, _), (gn, ge, _) = scene.start_ned_m, scene.goal_ned_m
        ax.plot([se, ge], [sn, gn], color="k", lw=0.8, ls=":")
        ax.plot(se, sn, "k^", ms=5)
        ax.plot(ge, gn, "k*", ms=7)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=6)
        ax.set_title(f"seed {verdict.seed}: {cause}", fontsize=8, color=colour)
    fig.suptitle(
        f"Failing scenes ({len(shown)} of {len(failing)}), plan view N up / E right; "
        "▲ start, ★ goal",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=100)
