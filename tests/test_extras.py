"""The onboard services install without the evaluation bench's extra (issue 33 item 4).

``pyproject.toml``'s ``[eval]`` extra holds Dask, distributed and matplotlib; the package's
own dependencies (what the Docker image installs) do not. The companion, plant-sim and
stereo-camera import nothing from it, ``stereo-avoid compile`` and ``paper`` do not need
Dask, and ``stereo-avoid montecarlo`` without it says which extra to install.
"""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

pytestmark = pytest.mark.processes  # fresh interpreters, so that imports are clean

ROOT = Path(__file__).resolve().parents[1]
EVAL_ONLY = ("dask", "distributed", "matplotlib")

# an interpreter in which the [eval] extra's packages cannot be imported
_BLOCK = """
import sys, importlib.abc
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in {blocked!r}:
            raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
sys.meta_path.insert(0, Block())
"""


def _names(requirements) -> set[str]:
    return {r.split(">")[0].split("<")[0].split("=")[0].split("[")[0].strip() for r in requirements}


def test_the_bench_dependencies_are_an_extra_the_dev_setup_installs():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    assert not _names(project["dependencies"]) & set(EVAL_ONLY), project["dependencies"]
    assert _names(project["optional-dependencies"]["eval"]) == set(EVAL_ONLY)
    assert "eval" in project["optional-dependencies"]["dev"][0]  # scripts/setup.sh: .[dev]


def _run(code: str, blocked: tuple[str, ...]) -> subprocess.CompletedProcess:
    script = _BLOCK.format(blocked=blocked) + code
    return subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120, cwd=ROOT
    )


@pytest.mark.parametrize(
    "module",
    ["companion.__main__", "companion.service", "companion.camera.__main__", "protocols"],
)
def test_onboard_services_import_without_the_extra(module):
    # plant-sim is left out: python-control, its LQ design, imports matplotlib itself
    done = _run(f"import {module}", EVAL_ONLY)
    assert done.returncode == 0, done.stderr


def test_plant_sim_and_the_cli_import_without_dask():
    done = _run(
        "import plant_sim.__main__, evaluation.cli, evaluation.kernels", ("dask", "distributed")
    )
    assert done.returncode == 0, done.stderr


def test_montecarlo_without_dask_names_the_extra(tmp_path):
    code = (
        "from evaluation.cli import main\n"
        f"raise SystemExit(main(['montecarlo', '--n', '1', '--out', {str(tmp_path)!r}]))\n"
    )
    done = _run(code, ("dask", "distributed"))
    assert done.returncode == 2, done.stderr
    assert "[eval] extra" in done.stderr and "distributed" in done.stderr
