"""Fixtures shared by the test modules (real plant-sim processes on 127.0.0.1)."""

from __future__ import annotations

from pathlib import Path

import pytest
from _plant_sim_proc import PlantProcess
from _tiers import Tier, classify_file

from protocols.threads import configure_threads


def pytest_configure(config):
    """The test processes run their kernels on the threads every product process uses
    (:mod:`protocols.threads`: one by default): lockstep flights in the test workers then
    cost what they cost in ``stereo-avoid``, not a barrier's wait on a shared machine."""
    configure_threads()


@pytest.hookimpl(tryfirst=True)  # before pytest-xdist reads the groups
def pytest_collection_modifyitems(config, items):
    """Mark every test with its module's tier (:mod:`_tiers`), unless the module states one,
    and order the work for pytest-xdist (:func:`_schedule`).

    ``bash scripts/test.sh --fast`` deselects ``processes`` by these marks; a module that
    states ``pytest.mark.<tier>`` keeps its own.
    """
    tiers: dict[Path, Tier] = {}
    names = {tier.value for tier in Tier}
    for item in items:
        if any(mark.name in names for mark in item.iter_markers()):
            continue
        path = Path(item.path)
        if path not in tiers:
            tiers[path] = classify_file(path)
        item.add_marker(getattr(pytest.mark, tiers[path].value))
    _schedule(items)


def _schedule(items) -> None:
    """Longest work first, and what shares a fixture on one worker.

    Under ``--dist loadgroup --no-loadscope-reorder`` (scripts/test.sh) pytest-xdist hands
    out work units in collection order: a module is one unit (its module-scoped fixtures,
    a lockstep flight or the SITL binary, are built once, and a file's flights never run
    beside each other), except a test marked ``own_flight`` (it flies its own scene and
    shares nothing), which is a unit by itself, so the Monte Carlo seeds and the speed
    bound's scenes spread over the workers. The slow lockstep flights go first, then the
    other flights, processes, and the quick tiers last, which fill the gaps at the end.
    """

    def rank(item) -> int:
        lockstep = item.get_closest_marker("lockstep") is not None
        slow = item.get_closest_marker("slow") is not None
        if lockstep:
            return 0 if slow else 1
        return 2 if item.get_closest_marker("processes") is not None else 3

    for item in items:
        if item.get_closest_marker("own_flight") is None:
            item.add_marker(pytest.mark.xdist_group(item.nodeid.split("::", 1)[0]))
    items.sort(key=rank)  # stable: a module's tests keep their order


@pytest.fixture
def plant_factory(tmp_path):
    procs: list[PlantProcess] = []

    def start(*args: str, log_dir=True) -> PlantProcess:
        extra = ["--log-dir", str(tmp_path / f"run{len(procs)}")] if log_dir else ["--no-logs"]
        p = PlantProcess(["--mavlink", "udpin:127.0.0.1:0", *extra, *args])
        procs.append(p)
        p.wait_ready()
        return p

    yield start
    for p in procs:
        p.stop()
        print(p.logs())  # pytest shows it only when the test fails
        p.close()
