"""How pytest-xdist hands out the suite: a module per work unit, ``own_flight`` tests alone.

``scripts/test.sh`` runs ``--dist loadscope --no-loadscope-reorder``; ``conftest.py``
returns :class:`FlightScheduling` for it. A module's tests are one work unit (its
module-scoped fixtures, a lockstep flight or the SITL binary, are built once, and a file's
flights never run beside each other), except the tests marked ``own_flight`` (each flies
its own scene and shares no fixture): each is a unit of its own, so the Monte Carlo seeds
and the speed bound's scenes spread over the workers. Modules that state the same
``SHARED_FLIGHT = "<name>"`` are one unit together: they read one session-scoped flight
(``conftest.py``), flown once on that worker. Units go out in collection order, which
``conftest.py`` sorts longest first.

The controller does not collect, so it reads the marks from the test modules' source
(:func:`own_flight_functions`). pytest-xdist's own ``xdist_group`` cannot do this here: with
pytest 9 its rename of the test ids has no effect.
"""

from __future__ import annotations

import ast
import functools
from pathlib import Path

from xdist.scheduler import LoadScopeScheduling

__all__ = ["FlightScheduling", "own_flight_functions", "shared_flight"]


@functools.cache
def _module(path: Path) -> ast.Module:
    try:
        return ast.parse(path.read_text())
    except (OSError, SyntaxError):
        return ast.Module(body=[], type_ignores=[])


def own_flight_functions(path: Path) -> frozenset[str]:
    """Names of the test functions in ``path`` decorated ``@pytest.mark.own_flight``."""
    names = set()
    for node in _module(path).body:
        if isinstance(node, ast.FunctionDef) and any(
            ast.unparse(d).endswith("mark.own_flight") for d in node.decorator_list
        ):
            names.add(node.name)
    return frozenset(names)


def shared_flight(path: Path) -> str | None:
    """The module's ``SHARED_FLIGHT`` string (None: it states none)."""
    for node in _module(path).body:
        if (
            isinstance(node, ast.Assign)
            and [ast.unparse(t) for t in node.targets] == ["SHARED_FLIGHT"]
            and isinstance(node.value, ast.Constant)
            and isinstance(node.value.value, str)
        ):
            return node.value.value
    return None


class FlightScheduling(LoadScopeScheduling):
    """Load-scope scheduling by module, with ``own_flight`` tests each a scope of its own."""

    def __init__(self, config, log=None) -> None:
        super().__init__(config, log)
        self._root = Path(config.rootpath)

    def _split_scope(self, nodeid: str) -> str:
        module, _, rest = nodeid.partition("::")
        function = rest.split("[", 1)[0]
        path = self._root / module
        if function in own_flight_functions(path):
            return nodeid
        shared = shared_flight(path)
        return module if shared is None else f"shared flight {shared}"
