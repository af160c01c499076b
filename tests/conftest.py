"""Fixtures shared by the test modules (real plant-sim processes on 127.0.0.1)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _plant_sim_proc import PlantProcess
from _schedule import FlightScheduling
from _tiers import Tier, classify_file

from protocols.threads import configure_threads


def pytest_configure(config):
    """The test processes run their kernels on the threads every product process uses
    (:mod:`protocols.threads`: one by default): lockstep flights in the test workers then
    cost what they cost in ``stereo-avoid``, not a barrier's wait on a shared machine."""
    configure_threads()


@pytest.hookimpl(tryfirst=True)  # the order pytest-xdist sees
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
    """Longest work first: the slow lockstep flights, then the other flights, processes,
    and the quick tiers last, which fill the gaps at the end (pytest-xdist hands out work
    units in this order, :mod:`_schedule`)."""

    def rank(item) -> int:
        lockstep = item.get_closest_marker("lockstep") is not None
        slow = item.get_closest_marker("slow") is not None
        if lockstep:
            return 0 if slow else 1
        return 2 if item.get_closest_marker("processes") is not None else 3

    items.sort(key=rank)  # stable: a module's tests keep their order


@pytest.hookimpl(tryfirst=True)  # before pytest-xdist's own choice
def pytest_xdist_make_scheduler(config, log):
    """``--dist loadscope``: by module, ``own_flight`` tests alone (:mod:`_schedule`)."""
    if config.getvalue("dist") == "loadscope":
        return FlightScheduling(config, log)
    return None


#: the companion's deaths simulated in the paper's flight: 20 evenly spaced times up to
#: 26.5 s (the flight takes ~26.7 s)
PAPER_KILL_TIMES_S = tuple(float(t) for t in np.linspace(0.0, 26.5, 20))


@pytest.fixture(scope="session")
def paper_flight():
    """The paper's §6 flight in lockstep at the default configuration, with the companion's
    death simulated at :data:`PAPER_KILL_TIMES_S` (each death's tail is flown on a copy of
    the plant, so the flight itself is the plain §6 flight): one flight for
    ``test_lockstep_paper.py`` and ``test_lockstep_envelope.py``, which state
    ``SHARED_FLIGHT = "paper"`` and so run on one worker (:mod:`_schedule`)."""
    from evaluation.harness import RunConfig, run_scene
    from evaluation.scenes import paper_scene

    return run_scene(paper_scene(), RunConfig(), kill_times_s=PAPER_KILL_TIMES_S)


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
