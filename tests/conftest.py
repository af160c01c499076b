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


def pytest_collection_modifyitems(config, items):
    """Mark every test with its module's tier (:mod:`_tiers`), unless the module states one.

    ``bash scripts/test.sh --fast`` deselects ``processes`` by these marks; a module that
    states ``pytestmark = pytest.mark.<tier>`` keeps its own.
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
