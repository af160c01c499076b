"""Test tiers: which of unit / contracts / lockstep / processes a test module belongs to.

A module's tier is read from what its source uses, so a new test file is classified
without anyone keeping a list (``conftest.py`` marks every collected test with it, and
``bash scripts/test.sh --fast`` deselects the slow tiers):

- ``processes``: it starts real processes or needs an outside binary: the process helpers
  (``_plant_sim_proc``, ``_companion_rig``, ``_starved``, ``_chromium``), ``ChildProcess``,
  the SIL/SITL rigs (``run_sil``, ``starve``), ``subprocess``, a Dask cluster, the
  ``plant_factory`` fixture, or a rig borrowed from another ``processes`` test module.
- ``lockstep``: it flies the in-process lockstep harness (``evaluation``'s ``run_scene``,
  ``fly_seed``, ``fly_record``, ``run_batch``, the Monte Carlo): no sockets, but seconds
  of CPU per flight.
- ``contracts``: conformance suites and checks on the code base itself (import
  directions, code shape, docs, these tiers).
- ``unit``: everything else (pure functions, in-process sockets at most).

A module whose guess is wrong states its tier with ``pytestmark = pytest.mark.<tier>``
(that wins). A module that shows signs of starting processes some other way
(``Popen``, ``multiprocessing``, ``os.fork``) without being classified ``processes`` is
*unclassified*: ``tests/test_test_tiers.py`` fails naming it, so the fast loop never
silently starts a process.
"""

from __future__ import annotations

import enum
import re
from pathlib import Path

__all__ = ["Tier", "classify", "classify_file", "explicit_tier", "unclassified_reason"]


class Tier(enum.Enum):
    """The four test tiers, fastest first; the value is the pytest marker's name."""

    UNIT = "unit"
    CONTRACTS = "contracts"
    LOCKSTEP = "lockstep"
    PROCESSES = "processes"


_PROCESS_SIGNS = re.compile(
    r"^\s*(?:from|import)\s+(?:_plant_sim_proc|_companion_rig|_starved|_chromium|subprocess)\b"
    r"|\bChildProcess\b|\brun_sil\b|\bstarve\b|\bplant_factory\b|\bmc_cluster\b"
    r"|\bLocalCluster\b|\bARDUCOPTER_SITL\b",
    re.MULTILINE,
)
_LOCKSTEP_SIGNS = re.compile(
    r"\brun_scene\b|\bfly_seed\b|\bfly_record\b|\brun_batch\b|\bmontecarlo\b"
)
_CONTRACT_SIGNS = re.compile(
    r"conformance|import direction|which package may import|code shape|shape the code"
    r"|\bREADME\b|test tiers",
    re.IGNORECASE,
)
# Ways of starting a process the rules above do not recognise.
_STRAY_PROCESS_SIGNS = re.compile(r"\bPopen\b|\bmultiprocessing\b|\bos\.fork\b|\bos\.system\b")
_EXPLICIT = re.compile(
    r"^pytestmark\s*=.*?\bpytest\.mark\.(unit|contracts|lockstep|processes)\b", re.MULTILINE
)


def explicit_tier(source: str) -> Tier | None:
    """The tier a module states with a module-level ``pytestmark``, or None."""
    match = _EXPLICIT.search(source)
    return Tier(match.group(1)) if match else None


def classify(source: str) -> Tier:
    """The tier of a test module from its source text (an explicit ``pytestmark`` wins)."""
    stated = explicit_tier(source)
    if stated is not None:
        return stated
    if _PROCESS_SIGNS.search(source):
        return Tier.PROCESSES
    if _LOCKSTEP_SIGNS.search(source):
        return Tier.LOCKSTEP
    head = source[:2000]  # the module docstring and imports say what a module is about
    if _CONTRACT_SIGNS.search(head):
        return Tier.CONTRACTS
    return Tier.UNIT


def unclassified_reason(source: str) -> str | None:
    """Why a module's tier cannot be trusted (it may start processes unseen), or None."""
    if explicit_tier(source) is not None or classify(source) is Tier.PROCESSES:
        return None
    stray = _STRAY_PROCESS_SIGNS.search(source)
    if stray is None:
        return None
    return (
        f"uses {stray.group(0)!r} but is classified {classify(source).value}: "
        "state its tier with `pytestmark = pytest.mark.processes` (or another tier)"
    )


_SIBLING_IMPORT = re.compile(r"^\s*from\s+(test_\w+)\s+import\b", re.MULTILINE)


def classify_file(path: Path, _seen: frozenset[Path] = frozenset()) -> Tier:
    """:func:`classify` of a test file; a module that borrows a rig from a ``processes``
    test module (``from test_companion_sil import Rig``) starts processes too."""
    source = path.read_text(encoding="utf-8")
    tier = classify(source)
    if tier is Tier.PROCESSES or explicit_tier(source) is not None:
        return tier
    for name in _SIBLING_IMPORT.findall(source):
        sibling = path.with_name(f"{name}.py")
        known = sibling.is_file() and sibling not in _seen
        if known and classify_file(sibling, _seen | {path}) is Tier.PROCESSES:
            return Tier.PROCESSES
    return tier
