"""Where the main loop's time goes: each phase of a frame's work and of the loop, counted.

A :class:`PhaseTimes` counts, per :class:`Phase`, how often it ran and how often it was
skipped (the companion not steering: guidance, planning, envelope and the hold's way out
serve only setpoints, issue 34). With clocks injected (PX4's ``getTime()`` way: the
service passes ``time.perf_counter_ns`` and ``time.thread_time_ns``) it also sums each
phase's wall and CPU time; without (the lockstep harness, replays, unit tests) it only
counts, so the pure core stays free of clocks and deterministic.

The wall time of a phase includes the time the process waited for a processor (a loaded
machine); its CPU time is the work itself. The figures go to the exit statistics
(``phases``) and the progress log.
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

__all__ = ["Phase", "PhaseClocks", "PhaseFigure", "PhaseTimes"]


class Phase(enum.Enum):
    """A part of the companion's work, per frame or per main-loop pass."""

    # per frame, in the avoidance pipeline (companion.pipeline)
    PERCEPTION = "perception"  # matcher (or depth frame) → depth, obstacle pixels
    KNOWN_SPACE = "known_space"  # the depth into the known-space map
    BOUNDARIES = "boundaries"  # the map's collision safety boundaries
    GUIDANCE = "guidance"  # collision cone, aiming point, modes (planning included)
    PLANNING = "planning"  # the known-space path search or follow (inside guidance)
    ENVELOPE = "envelope"  # the safety envelope's carrot and speed bound
    HOLD = "hold"  # a hold's or a carrot's way out of a boundary
    # per frame, in the core around the pipeline
    SECTORS = "sectors"  # OBSTACLE_DISTANCE's sectors of the map
    STATUS = "status"  # the frame's status document
    # per main-loop pass, in the service
    MAVLINK = "mavlink"  # parse what arrived and step the core on each message
    TICK = "tick"  # the core's timers
    FRAME = "frame"  # the whole frame step (the pipeline's phases and the core's)
    SNAPSHOT = "snapshot"  # the map copy for the OBSTACLE_DISTANCE process


@dataclass(frozen=True)
class PhaseClocks:
    """The clocks a :class:`PhaseTimes` reads [ns]: wall (e.g. ``time.perf_counter_ns``)
    and this thread's CPU time (``time.thread_time_ns``)."""

    wall_ns: Callable[[], int]
    cpu_ns: Callable[[], int]


@dataclass(slots=True)
class PhaseFigure:
    """One phase's figures: runs, skips, and (with clocks) time summed and the longest."""

    runs: int = 0
    skipped: int = 0
    wall_ns: int = 0
    cpu_ns: int = 0
    max_wall_ns: int = 0

    def as_dict(self) -> dict[str, float | int]:
        """Counts, and per run the mean wall and CPU time and the longest wall time [ms]."""
        runs = max(self.runs, 1)
        return {
            "runs": self.runs,
            "skipped": self.skipped,
            "mean_wall_ms": round(self.wall_ns / runs * 1e-6, 3),
            "mean_cpu_ms": round(self.cpu_ns / runs * 1e-6, 3),
            "max_wall_ms": round(self.max_wall_ns * 1e-6, 3),
            "total_cpu_s": round(self.cpu_ns * 1e-9, 3),
        }


class PhaseTimes:
    """Runs, skips and (with ``clocks``) times per :class:`Phase`.

    Parameters
    ----------
    clocks : PhaseClocks, optional
        None: counts only (no clock is read).
    """

    def __init__(self, clocks: PhaseClocks | None = None) -> None:
        self._clocks = clocks
        self.figures = {phase: PhaseFigure() for phase in Phase}

    @contextmanager
    def timed(self, phase: Phase) -> Iterator[None]:
        """Count one run of ``phase`` around the ``with`` body (timed with clocks)."""
        figure = self.figures[phase]
        clocks = self._clocks
        if clocks is None:
            figure.runs += 1
            yield
            return
        wall0, cpu0 = clocks.wall_ns(), clocks.cpu_ns()
        try:
            yield
        finally:
            wall = clocks.wall_ns() - wall0
            figure.runs += 1
            figure.wall_ns += wall
            figure.cpu_ns += clocks.cpu_ns() - cpu0
            figure.max_wall_ns = max(figure.max_wall_ns, wall)

    def skip(self, *phases: Phase) -> None:
        """Count ``phases`` as skipped once."""
        for phase in phases:
            self.figures[phase].skipped += 1

    def runs(self, phase: Phase) -> int:
        return self.figures[phase].runs

    def skipped(self, phase: Phase) -> int:
        return self.figures[phase].skipped

    def as_dict(self) -> dict[str, dict[str, float | int]]:
        """Every phase that ran or was skipped, by name."""
        return {
            phase.value: figure.as_dict()
            for phase, figure in self.figures.items()
            if figure.runs or figure.skipped
        }

    def text(self) -> str:
        """One line: each phase's mean CPU time per run [ms] and its skips."""
        parts = []
        for phase, figure in self.figures.items():
            if not (figure.runs or figure.skipped):
                continue
            mean = figure.cpu_ns / max(figure.runs, 1) * 1e-6
            skipped = f" ({figure.skipped} skipped)" if figure.skipped else ""
            parts.append(f"{phase.value} {figure.runs}x{mean:.1f}ms{skipped}")
        return ", ".join(parts)
