"""A progress bar for long Monte Carlo batches: done/total, rate, ETA and the bad news.

On a terminal the bar redraws in place; into a file or pipe (a nightly job's log) it
prints a line every ``log_every_s`` seconds and at the end. The rate counts only the
scenes flown in this session (a resumed batch does not look faster than it is).
"""

from __future__ import annotations

import math
import time
from typing import IO

__all__ = ["ProgressBar", "format_duration"]


def format_duration(seconds: float) -> str:
    """``h:mm:ss`` (or ``--:--`` when unknown)."""
    if not math.isfinite(seconds) or seconds < 0:
        return "--:--"
    s = round(seconds)
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


class ProgressBar:
    """Progress of ``total`` scenes, ``already_done`` of them finished before this session.

    Parameters
    ----------
    total, already_done : int
        Scenes in the batch; scenes finished by an earlier (resumed) session.
    stream : text stream
        Where to draw.
    tty : bool, optional
        Redraw in place; default: ``stream.isatty()``.
    log_every_s : float
        Interval between lines when not a terminal [s, wall time].
    clock : callable, optional
        Wall clock in seconds (tests pass their own).
    """

    WIDTH = 30

    def __init__(
        self,
        total: int,
        already_done: int,
        stream: IO[str],
        *,
        tty: bool | None = None,
        log_every_s: float = 10.0,
        clock=time.monotonic,
    ) -> None:
        self.total = total
        self.done = already_done
        self.collisions = 0
        self.unsafe = 0
        self._session_start = already_done
        self._stream = stream
        self._tty = stream.isatty() if tty is None else tty
        self._log_every_s = log_every_s
        self._clock = clock
        self._t0 = clock()
        self._last_line = -math.inf
        self._ended = False

    @property
    def rate_per_min(self) -> float:
        """Scenes per minute in this session (NaN before the first)."""
        elapsed = self._clock() - self._t0
        flown = self.done - self._session_start
        return 60.0 * flown / elapsed if flown and elapsed > 0 else math.nan

    @property
    def eta_s(self) -> float:
        """Seconds left at the session's rate (NaN while unknown)."""
        rate = self.rate_per_min
        return 60.0 * (self.total - self.done) / rate if rate > 0 else math.nan

    def line(self) -> str:
        """The bar as one line of text."""
        frac = self.done / self.total if self.total else 1.0
        filled = round(self.WIDTH * frac)
        bar = "#" * filled + "." * (self.WIDTH - filled)
        rate = self.rate_per_min
        rate_s = f"{rate:5.1f}" if math.isfinite(rate) else "  -  "
        return (
            f"[{bar}] {self.done}/{self.total} {100 * frac:3.0f}%  {rate_s} scenes/min  "
            f"ETA {format_duration(self.eta_s)}  collisions {self.collisions}  "
            f"unsafe {self.unsafe}"
        )

    def update(self, *, collided: bool, safe: bool) -> None:
        """One more scene finished."""
        self.done += 1
        self.collisions += int(collided)
        self.unsafe += int(not safe)
        self._draw(final=self.done >= self.total)

    def close(self) -> None:
        """Draw the last state and end the line."""
        self._draw(final=True)

    def _draw(self, *, final: bool) -> None:
        if self._ended:
            return
        self._ended = final
        now = self._clock()
        if self._tty:
            self._stream.write("\r" + self.line() + ("\n" if final else ""))
        elif final or now - self._last_line >= self._log_every_s:
            self._stream.write(self.line() + "\n")
            self._last_line = now
        else:
            return
        self._stream.flush()
