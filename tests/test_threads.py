"""Thread counts per process (issue 32 item 7): one thread by default, raised on request,
explicit library variables win, a bad value is a configuration error of every process."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from protocols.threads import THREADS_ENV, threads_from

_PROBE = (
    "import json; from protocols.threads import configure_threads; c = configure_threads(); "
    "import cv2, numba; print(json.dumps([c.numba, c.opencv, numba.get_num_threads(), "
    "cv2.getNumThreads()]))"
)


def _clean_env(**extra: str) -> dict[str, str]:
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in (THREADS_ENV, "NUMBA_NUM_THREADS", "OMP_NUM_THREADS")
    }
    env.update(extra)
    return env


def _probe(**extra: str) -> list[int]:
    done = subprocess.run(
        [sys.executable, "-c", _PROBE],
        env=_clean_env(**extra),
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_default_is_one_thread_and_the_variable_raises_it():
    assert threads_from({}) == 1
    assert threads_from({THREADS_ENV: " 3 "}) == 3


@pytest.mark.parametrize("text", ["0", "-1", "two", "1.5", "257"])
def test_a_bad_count_names_the_variable(text):
    with pytest.raises(ValueError, match=THREADS_ENV):
        threads_from({THREADS_ENV: text})


def test_a_process_runs_its_kernels_and_opencv_on_one_thread_by_default():
    assert _probe() == [1, 1, 1, 1]


def test_the_variable_sets_both_and_an_explicit_numba_count_wins():
    assert _probe(**{THREADS_ENV: "2"}) == [2, 2, 2, 2]
    assert _probe(NUMBA_NUM_THREADS="2") == [2, 1, 2, 1]


@pytest.mark.parametrize("module", ["companion", "plant_sim", "companion.camera", "evaluation.cli"])
def test_every_process_refuses_a_bad_count_as_a_configuration_error(module):
    done = subprocess.run(
        [sys.executable, "-m", module, "--help"],
        env=_clean_env(**{THREADS_ENV: "many"}),
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 2, done.stdout + done.stderr
    assert f"configuration error: {THREADS_ENV}" in done.stderr
