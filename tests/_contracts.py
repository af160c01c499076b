"""Conformance by discovery: every class of ours that implements a contract, read from source.

A conformance suite that lists its implementations by hand misses the ones nobody added
(issue 33: two were missed). As python-control's ``kwargs_test`` discovers every public
function and fails on one it does not cover, :func:`implementations` finds every class in
our packages that implements a contract method, so the suite can fail on any it has no
entry for. A class implements it when it defines ``method`` with the return annotation
``returns`` (``compute`` → ``DepthMap``; ``X | None`` counts as ``X``), or inherits from
such a class (by the base's name); a ``Protocol`` class (the contract itself) does not.
The source is parsed, not imported: a module that needs an optional extra is found all
the same.
"""

from __future__ import annotations

import ast
from pathlib import Path

__all__ = ["ROOT", "SEARCHED", "check_coverage", "implementations"]

ROOT = Path(__file__).resolve().parents[1]
SEARCHED = ("protocols", "companion", "plant_sim", "evaluation", "benchmarks", "scripts")


def _module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _name(node: ast.expr) -> str:
    """The last dotted part of a base or an annotation (``"DepthMap"`` strings too)."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value.rsplit(".", 1)[-1].strip()
    if isinstance(node, ast.Subscript):
        return _name(node.value)
    if isinstance(node, ast.Attribute):
        return node.attr
    return node.id if isinstance(node, ast.Name) else ""


def _returned(node: ast.expr) -> set[str]:
    """The names a return annotation allows: ``X``, and each side of ``X | None``."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return _returned(ast.parse(node.value, mode="eval").body)
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.BitOr):
        return _returned(node.left) | _returned(node.right)
    return {_name(node)}


def _defines(cls: ast.ClassDef, method: str, returns: str) -> bool:
    return any(
        isinstance(item, ast.FunctionDef | ast.AsyncFunctionDef)
        and item.name == method
        and item.returns is not None
        and returns in _returned(item.returns)
        for item in cls.body
    )


def implementations(
    method: str, returns: str, root: Path = ROOT, searched: tuple[str, ...] = SEARCHED
) -> list[str]:
    """Qualified names (``package.module.Class``) of the classes under ``root``'s
    ``searched`` folders that implement ``method -> returns`` (module docstring), sorted."""
    classes: dict[str, ast.ClassDef] = {}
    for folder in searched:
        for path in sorted((root / folder).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
            module = _module_name(path, root)
            for node in ast.walk(tree):
                if isinstance(node, ast.ClassDef):
                    classes[f"{module}.{node.name}"] = node
    found = {
        name
        for name, cls in classes.items()
        if _defines(cls, method, returns) and "Protocol" not in {_name(b) for b in cls.bases}
    }
    while True:  # subclasses of an implementation implement it too
        names = {name.rsplit(".", 1)[1] for name in found}
        more = {
            name
            for name, cls in classes.items()
            if name not in found and names & {_name(b) for b in cls.bases}
        }
        if not more:
            return sorted(found)
        found |= more


def check_coverage(discovered, entries, what: str, at_least: int) -> None:
    """Fail unless every discovered implementation has an entry (how the suite builds and
    feeds it) and every entry names one that is discovered; ``at_least`` guards discovery
    itself (finding nothing must not pass)."""
    assert len(discovered) >= at_least, f"discovered only {discovered}"
    missing = sorted(set(discovered) - set(entries))
    assert not missing, f"{what} without a conformance entry: {missing}"
    stale = sorted(set(entries) - set(discovered))
    assert not stale, f"conformance entries that are not {what}: {stale}"
