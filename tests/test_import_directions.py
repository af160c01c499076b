"""The layout is the architecture (DESIGN.md, "What the product is"; issue 33).

Which package may import which, checked on the source (every ``import`` anywhere in a
module, top level or inside a function):

* ``protocols``: the only code the two processes share; imports none of ours;
* ``companion`` and ``plant_sim``: each imports ``protocols`` only, never the other;
* ``evaluation``: the bench, the one place that imports both; nothing imports it except
  the tests, benchmarks and scripts that drive it.

And no import cycles between modules: a cycle is two modules that cannot be understood,
tested or moved apart.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
OURS = ("protocols", "companion", "plant_sim", "evaluation")
ALLOWED = {
    "protocols": {"protocols"},
    "companion": {"companion", "protocols"},
    "plant_sim": {"plant_sim", "protocols"},
    "evaluation": {"evaluation", "companion", "plant_sim", "protocols"},
}


def _module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _imports(path: Path, root: Path) -> list[tuple[int, str]]:
    """Absolute names of every module ``path`` imports (relative imports resolved)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    here = _module_name(path, root).split(".")
    package = here if path.name == "__init__.py" else here[:-1]
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package[: len(package) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            # ``from pkg import mod`` imports the module pkg.mod when there is one
            found += [(node.lineno, f"{base}.{a.name}") for a in node.names]
            found.append((node.lineno, base))
    return found


def _modules(root: Path, packages=OURS) -> dict[str, Path]:
    return {
        _module_name(p, root): p
        for pkg in packages
        if (root / pkg).is_dir()
        for p in sorted((root / pkg).rglob("*.py"))
    }


def _graph(root: Path, packages=OURS) -> dict[str, set[str]]:
    modules = _modules(root, packages)
    graph = {}
    for name, path in modules.items():
        edges = set()
        for _, target in _imports(path, root):
            # the longest prefix that is one of our modules (a name inside a module
            # resolves to the module)
            parts = target.split(".")
            while parts and ".".join(parts) not in modules:
                parts.pop()
            if parts and ".".join(parts) != name:
                edges.add(".".join(parts))
        graph[name] = edges
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index, low, on_stack, stack, found = {}, {}, set(), [], []
    counter = 0
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            node, edges = work[-1]
            nxt = next(edges, None)
            if nxt is not None:
                if nxt not in index:
                    index[nxt] = low[nxt] = counter
                    counter += 1
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, iter(sorted(graph.get(nxt, ())))))
                elif nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def _wrong_directions(root: Path, package: str) -> list[str]:
    wrong = []
    for path in _modules(root, (package,)).values():
        for line, target in _imports(path, root):
            top = target.split(".")[0]
            if top in OURS and top not in ALLOWED[package]:
                wrong.append(f"{path.relative_to(root)}:{line} imports {target}")
    return sorted(set(wrong))


def _write(root: Path, files: dict[str, str]) -> None:
    for rel, text in files.items():
        p = root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text, encoding="utf-8")


def test_the_checks_find_a_wrong_direction_and_a_cycle(tmp_path):
    _write(
        tmp_path,
        {
            "protocols/__init__.py": "",
            "companion/__init__.py": "",
            "companion/a.py": "from . import b\n",
            "companion/b.py": "def f():\n    from companion.a import x\n",
            "companion/c.py": "from companion import b\n",
            "plant_sim/__init__.py": "",
            "plant_sim/x.py": "import protocols\nfrom companion.c import y\n",
        },
    )
    assert _wrong_directions(tmp_path, "plant_sim") == [
        "plant_sim/x.py:2 imports companion.c",
        "plant_sim/x.py:2 imports companion.c.y",
    ]
    assert _wrong_directions(tmp_path, "companion") == []
    assert _cycles(_graph(tmp_path)) == [["companion.a", "companion.b"]]


@pytest.mark.parametrize("package", OURS)
def test_each_package_imports_only_what_it_may(package):
    assert _modules(ROOT, (package,)), f"no modules found in {package}/"
    wrong = _wrong_directions(ROOT, package)
    assert not wrong, f"{package} may import only {sorted(ALLOWED[package])}:\n" + "\n".join(wrong)


def test_no_import_cycles():
    cycles = _cycles(_graph(ROOT))
    assert not cycles, "import cycles (break them):\n" + "\n".join(" ↔ ".join(c) for c in cycles)
