"""The test tiers (tests/_tiers.py, docs/testing.md): every module classified, none unsure.

``bash scripts/test.sh --fast`` deselects tiers by the markers ``conftest.py`` sets from
:mod:`_tiers`; a module the rules misread would start processes in the fast loop or hide
a fast check from it. These tests check the rules on the suite itself.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from _tiers import Tier, classify, classify_file, unclassified_reason

# Stated, not guessed: this module names `multiprocessing` in a test string.
pytestmark = pytest.mark.contracts

TESTS = Path(__file__).resolve().parent
MODULES = sorted(TESTS.glob("test_*.py"))


@pytest.mark.parametrize("path", MODULES, ids=lambda p: p.name)
def test_every_test_module_has_a_tier_it_can_be_trusted_with(path):
    reason = unclassified_reason(path.read_text(encoding="utf-8"))
    assert reason is None, f"{path.name} is unclassified: {reason}"
    assert classify_file(path) in Tier


@pytest.mark.parametrize(
    ("name", "tier"),
    [
        ("test_lq.py", Tier.UNIT),
        ("test_guidance_cone.py", Tier.UNIT),
        ("test_depth_source.py", Tier.CONTRACTS),
        ("test_import_directions.py", Tier.CONTRACTS),
        ("test_code_shape.py", Tier.CONTRACTS),
        ("test_lockstep_paper.py", Tier.LOCKSTEP),
        ("test_lockstep_montecarlo.py", Tier.LOCKSTEP),
        ("test_companion_sil.py", Tier.PROCESSES),
        ("test_montecarlo_cluster.py", Tier.PROCESSES),
        ("test_sitl_arducopter.py", Tier.PROCESSES),
        # a unit-looking module that borrows the process rig of test_companion_sil
        ("test_companion_takeoff.py", Tier.PROCESSES),
    ],
)
def test_known_modules_land_in_their_tier(name, tier):
    path = TESTS / name
    if not path.is_file():
        pytest.fail(f"{name} is gone: pick another module of tier {tier.value} here")
    assert classify_file(path) is tier, f"{name}: {classify_file(path).value}, not {tier.value}"


def test_an_explicit_pytestmark_wins_and_a_stray_process_is_caught():
    plain = '"""Pure maths."""\nimport math\n'
    stray = plain + "from multiprocessing import Process\n"
    stated = "import pytest\npytestmark = pytest.mark.processes\n" + stray
    assert classify(plain) is Tier.UNIT and unclassified_reason(plain) is None
    assert unclassified_reason(stray) is not None
    assert classify(stated) is Tier.PROCESSES and unclassified_reason(stated) is None
    subprocess_user = plain + "import subprocess\n"
    assert classify(subprocess_user) is Tier.PROCESSES
    lockstep = plain + "from evaluation.harness import run_scene\n"
    assert classify(lockstep) is Tier.LOCKSTEP


def test_every_collected_test_carries_exactly_one_tier(request):
    tiers = {tier.value for tier in Tier}
    for item in request.session.items:
        marks = {mark.name for mark in item.iter_markers()} & tiers
        assert len(marks) == 1, f"{item.nodeid}: tiers {sorted(marks)}"
