"""The shape the code keeps (issue 11): no function over 80 lines outside compiled kernels.

Long functions are where concerns pile up; numba kernels are exempt (a compiled loop is
one unit, and splitting it costs calls in the innermost loop). Docstrings count.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("companion", "plant_sim", "protocols", "evaluation", "benchmarks", "scripts")
MAX_LINES = 80


def _is_kernel(node: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    return any("njit" in ast.unparse(d) or "numba" in ast.unparse(d) for d in node.decorator_list)


def _long_functions(path: Path, root: Path = ROOT) -> list[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and not _is_kernel(node):
            n = node.end_lineno - node.lineno + 1
            if n > MAX_LINES:
                found.append(f"{path.relative_to(root)}:{node.lineno} {node.name} ({n} lines)")
    return found


def _sources() -> list[Path]:
    return sorted(p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py"))


def test_the_check_finds_a_long_function(tmp_path):
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_LINES))
    long_file = tmp_path / "long.py"
    long_file.write_text(f"def too_long():\n{body}\n", encoding="utf-8")
    kernel = tmp_path / "kernel.py"
    kernel.write_text(f"import numba\n@numba.njit\ndef k():\n{body}\n", encoding="utf-8")
    assert _long_functions(long_file, tmp_path) == [f"long.py:1 too_long ({MAX_LINES + 1} lines)"]
    assert _long_functions(kernel, tmp_path) == []


@pytest.mark.parametrize("package", PACKAGES)
def test_no_function_over_80_lines(package):
    assert _sources(), "no sources found"
    found = [
        f for p in _sources() if p.relative_to(ROOT).parts[0] == package for f in _long_functions(p)
    ]
    assert not found, "split these functions:\n" + "\n".join(found)
