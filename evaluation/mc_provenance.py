"""Which code flew a Monte Carlo seed: a fingerprint of the source that decides a verdict.

A verdict is a function of the seed *and of the code* (perception, guidance, plant, scenes).
A batch of 100k scenes is resumed over days and flown by workers of a shared cluster, so
every results record carries the fingerprint of the code that flew it
(:func:`code_fingerprint`, computed in the worker), a resumed batch refuses to mix it with
another unless told to, and the report says which code flew how many seeds.

The fingerprint hashes the Python source of the packages that decide a verdict
(``companion``, ``plant_sim``, ``protocols``): any edit, even a comment, changes it. That is
the conservative choice for a safety regression; a change known not to move a verdict can
finish a batch with ``--allow-code-change``, and the report lists both fingerprints.
"""

from __future__ import annotations

import functools
import hashlib
import importlib
from collections import Counter
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

__all__ = [
    "UNKNOWN_CODE",
    "VERDICT_PACKAGES",
    "code_counts",
    "code_fingerprint",
    "source_fingerprint",
]

VERDICT_PACKAGES: tuple[str, ...] = ("companion", "plant_sim", "protocols")
UNKNOWN_CODE = "unknown"  # a record written before records carried their code
_DIGITS = 16  # hex digits kept: 64 bits, no accidental collision in any plausible history


def source_fingerprint(roots: Iterable[Path]) -> str:
    """SHA-256 (first 16 hex digits) of every ``*.py`` file under ``roots``: each file's
    path relative to the parent of its root, then its bytes, in sorted path order
    (compiled caches are not source and are skipped)."""
    files: list[tuple[str, Path]] = []
    for root in roots:
        root = Path(root)
        for path in root.rglob("*.py"):
            if "__pycache__" not in path.parts:
                files.append((path.relative_to(root.parent).as_posix(), path))
    digest = hashlib.sha256()
    for name, path in sorted(files):
        digest.update(name.encode() + b"\0")
        digest.update(path.read_bytes())
        digest.update(b"\0")
    return digest.hexdigest()[:_DIGITS]


@functools.cache
def code_fingerprint() -> str:
    """:func:`source_fingerprint` of the installed :data:`VERDICT_PACKAGES` (once per
    process: the source a process imported does not change under it)."""
    roots = [Path(importlib.import_module(name).__file__).parent for name in VERDICT_PACKAGES]
    return source_fingerprint(roots)


def code_counts(records: Iterable[Mapping[str, Any]]) -> dict[str, int]:
    """Seeds per code fingerprint (:data:`UNKNOWN_CODE` for records without one), most
    seeds first."""
    counts = Counter(str(r.get("code") or UNKNOWN_CODE) for r in records)
    return dict(counts.most_common())
