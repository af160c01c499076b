"""``stereo-avoid compile`` (what setup runs) reaches every numba kernel of the product, so
no process compiles one at its first frame."""

import subprocess
import sys

import pytest

# In a fresh interpreter: compile (from the cache: setup ran it), then list every numba
# kernel of the product's modules that has no compiled signature of its own, unless only
# other kernels call it (a caller loaded from the cache carries its callees' code, and
# inline="always" helpers are compiled into their callers).
_SCRIPT = """
import importlib, pkgutil, types, numba
from numba.core.registry import CPUDispatcher
from evaluation.kernels import compile_kernels
lines = []
compile_kernels(jobs=1, log=lines.append)
print("\\n".join(lines))
kernels = {}
for package in ("companion", "plant_sim", "protocols"):
    root = importlib.import_module(package)
    for info in pkgutil.walk_packages(root.__path__, package + "."):
        if info.name.endswith("__main__"):
            continue
        module = importlib.import_module(info.name)
        for name, obj in vars(module).items():
            if isinstance(obj, CPUDispatcher) and obj.__module__ == info.name:
                kernels[(info.name, name)] = obj
def referenced(fn):  # the objects a function names: globals, and attributes of modules
    names = fn.__code__.co_names
    for name in names:
        value = fn.__globals__.get(name)
        yield value
        if isinstance(value, types.ModuleType):
            yield from (getattr(value, attr, None) for attr in names)
def called_by_kernels(kernel):
    return any(
        other is not kernel and any(ref is kernel for ref in referenced(other.py_func))
        for other in kernels.values()
    )
missing = [
    m + "." + n for (m, n), k in kernels.items() if not k.signatures and not called_by_kernels(k)
]
print("kernels", len(kernels))
print("missing", " ".join(missing))
"""


@pytest.mark.slow
def test_compile_reaches_every_kernel():
    out = subprocess.run(
        [sys.executable, "-c", _SCRIPT], capture_output=True, text=True, timeout=600, check=False
    )
    assert out.returncode == 0, out.stderr[-3000:]
    lines = out.stdout.splitlines()
    assert any(line.startswith("compile: every kernel is in numba's cache") for line in lines)
    n = int(next(line for line in lines if line.startswith("kernels")).split()[1])
    assert n >= 20, out.stdout  # the renderer, perception, known space, dynamics, control
    missing = next(line for line in lines if line.startswith("missing")).split()[1:]
    assert missing == [], f"kernels stereo-avoid compile does not reach: {missing}"
