"""A slow, busy companion computer on this machine: a process gets a fraction of one core.

Issue 32 item 5: the companion is run with a share of one CPU core, the stand-in for a
Raspberry Pi-class computer that also runs a camera driver and a logger. Two mechanisms,
the first that works here is used:

``cgroup``
    A CPU bandwidth quota on a cgroup of its own (cgroup v2 ``cpu.max`` or v1
    ``cpu.cfs_quota_us``), with a short period (10 ms) so the process is slowed steadily
    rather than stopped for long stretches. Needs write access to the cgroup tree (root
    in CI containers); the process and every thread it starts later are in it.
``taskset``
    The process is pinned to one core beside ``k`` spinning processes pinned to the same
    core at the same priority; the scheduler's fair share then gives it about
    ``1 / (k + 1)`` of the core (0.5, 0.33, 0.25 ...: the fraction is rounded to that).
    Costs one busy core; needs only ``taskset`` (util-linux).

:func:`starve` says which mechanism it used; :func:`available` says why neither works
(the caller reports it, e.g. a test's skip reason).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import sys
import uuid
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["Starvation", "available", "starve"]

_CGROUP_ROOT = Path("/sys/fs/cgroup")
_PERIOD_US = 10_000


def _cgroup_dirs() -> tuple[Path, str] | None:
    """(directory to create a child cgroup in, "v2" or "v1") if writable."""
    v2 = _CGROUP_ROOT / "cgroup.controllers"
    if v2.exists() and "cpu" in v2.read_text().split() and os.access(_CGROUP_ROOT, os.W_OK):
        return _CGROUP_ROOT, "v2"
    v1 = _CGROUP_ROOT / "cpu"
    if (v1 / "cpu.cfs_quota_us").exists() and os.access(v1, os.W_OK):
        return v1, "v1"
    return None


def available() -> tuple[str | None, str]:
    """The mechanism :func:`starve` would use, or None and why neither works."""
    if _cgroup_dirs() is not None:
        return "cgroup", "CPU bandwidth quota on a cgroup"
    if shutil.which("taskset") and (os.cpu_count() or 1) >= 1:
        return "taskset", "pinned to one core beside spinning processes"
    return None, (
        "cannot starve a process here: no writable cgroup CPU controller (run as root) "
        "and no taskset (util-linux)"
    )


@dataclass
class Starvation:
    """A process held to ``core_fraction`` of one core until :meth:`close`."""

    core_fraction: float
    mechanism: str
    detail: str
    _cgroup: Path | None = None
    _spinners: list[subprocess.Popen] = field(default_factory=list)

    def describe(self) -> str:
        return f"{self.core_fraction:.2f} of one core ({self.mechanism}: {self.detail})"

    def close(self) -> None:
        for proc in self._spinners:
            proc.kill()
            proc.wait()
        self._spinners.clear()
        if self._cgroup is not None:
            parent = self._cgroup.parent / "cgroup.procs"
            try:  # anything still inside goes back to the parent before the group goes
                for pid in (self._cgroup / "cgroup.procs").read_text().split():
                    parent.write_text(pid)
            except OSError:
                pass
            with contextlib.suppress(OSError):
                self._cgroup.rmdir()
            self._cgroup = None

    def __enter__(self) -> Starvation:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _by_cgroup(pid: int, core_fraction: float) -> Starvation | None:
    found = _cgroup_dirs()
    if found is None:
        return None
    root, version = found
    group = root / f"stereo-avoid-starve-{uuid.uuid4().hex[:12]}"
    quota_us = max(1000, round(core_fraction * _PERIOD_US))
    try:
        group.mkdir()
        if version == "v2":
            (group / "cpu.max").write_text(f"{quota_us} {_PERIOD_US}")
        else:
            (group / "cpu.cfs_period_us").write_text(str(_PERIOD_US))
            (group / "cpu.cfs_quota_us").write_text(str(quota_us))
        (group / "cgroup.procs").write_text(str(pid))
    except OSError:
        with contextlib.suppress(OSError):
            group.rmdir()
        return None
    detail = f"cgroup {version} quota {quota_us} µs per {_PERIOD_US} µs"
    return Starvation(quota_us / _PERIOD_US, "cgroup", detail, _cgroup=group)


def _by_taskset(pid: int, core_fraction: float) -> Starvation:
    core = (os.cpu_count() or 1) - 1
    n_spin = max(0, round(1.0 / core_fraction) - 1)
    spin = "while True: pass"
    subprocess.run(
        ["taskset", "-a", "-p", "-c", str(core), str(pid)], check=True, capture_output=True
    )
    spinners = [
        subprocess.Popen(["taskset", "-c", str(core), sys.executable, "-c", spin])
        for _ in range(n_spin)
    ]
    detail = f"core {core} shared with {n_spin} spinning processes"
    return Starvation(1.0 / (n_spin + 1), "taskset", detail, _spinners=spinners)


def starve(pid: int, core_fraction: float) -> Starvation:
    """Hold process ``pid`` to ``core_fraction`` (0, 1] of one core.

    Raises
    ------
    ValueError
        For a fraction outside (0, 1].
    RuntimeError
        When neither mechanism works here (the message says why).
    """
    if not 0.0 < core_fraction <= 1.0:
        raise ValueError(f"core_fraction must be in (0, 1], got {core_fraction!r}")
    starved = _by_cgroup(pid, core_fraction)
    if starved is not None:
        return starved
    mechanism, why = available()
    if mechanism is None:
        raise RuntimeError(why)
    return _by_taskset(pid, core_fraction)
