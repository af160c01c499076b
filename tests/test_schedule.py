"""How the suite is spread over pytest-xdist workers (tests/_schedule.py): a module per work
unit, ``own_flight`` tests alone, modules that share a flight together."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from _schedule import FlightScheduling, own_flight_functions, shared_flight

pytestmark = pytest.mark.contracts

TESTS = Path(__file__).parent


def _scope(nodeid: str) -> str:
    scheduler = FlightScheduling.__new__(FlightScheduling)  # no xdist session needed
    scheduler._root = TESTS.parent
    return scheduler._split_scope(nodeid)


def test_own_flight_tests_are_units_of_their_own_and_other_tests_go_by_module():
    seed = "tests/test_lockstep_montecarlo.py::test_monte_carlo_sample_has_no_collision[103]"
    assert _scope(seed) == seed
    quick = "tests/test_lockstep_montecarlo.py::test_random_scenes_are_reproducible_and_valid"
    assert _scope(quick) == "tests/test_lockstep_montecarlo.py"
    assert _scope("tests/test_lq.py::test_attitude_gains_equal_eq31") == "tests/test_lq.py"


def test_modules_sharing_a_flight_are_one_unit():
    a = _scope("tests/test_lockstep_paper.py::test_goal_reached_without_collision")
    b = _scope("tests/test_lockstep_envelope.py::test_fast_profile_flies_faster_than_the_paper")
    assert a == b == "shared flight paper"


def test_every_module_that_reads_a_session_flight_states_it_shares_it():
    """A module using conftest.py's session-scoped paper_flight without SHARED_FLIGHT would
    fly it again on whichever worker it lands on."""
    for path in sorted(TESTS.glob("test_*.py")):
        uses = any(
            isinstance(node, ast.FunctionDef) and "paper_flight" in {a.arg for a in node.args.args}
            for node in ast.walk(ast.parse(path.read_text()))
        )
        assert (shared_flight(path) == "paper") == uses, path.name


def test_own_flight_marks_are_read_from_the_source():
    assert own_flight_functions(TESTS / "test_lockstep_speed_bound.py") == {
        "test_speed_never_exceeds_the_stated_limit_at_the_fast_airframe",
        "test_speed_never_exceeds_the_stated_limit_on_a_staged_climb_at_the_fast_airframe",
    }
    assert own_flight_functions(TESTS / "test_lq.py") == frozenset()
