"""Monte Carlo at scale (issue 17): a seed's verdict is the same in this process, on any
worker of a local Dask cluster and in ``stereo-avoid replay``; an interrupted batch
resumes without flying a finished seed again. Short horizons (``max_time_s``) keep it fast:
what is compared is the determinism of the path, not the outcome of whole flights."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from evaluation.cli import main
from evaluation.mc_cluster import dask_client, fly_on_cluster
from evaluation.mc_provenance import code_counts, code_fingerprint, source_fingerprint
from evaluation.mc_results import (
    BatchSpec,
    ResultsFile,
    ResultsFileError,
    verdict_from_record,
    verdict_to_record,
)
from evaluation.montecarlo import error_verdict, fly_record, fly_seed

SEEDS = range(40, 60)  # 20 seeds, five of each family
HORIZON_S = 1.5  # simulation seconds per scene


@pytest.fixture(autouse=True)
def _restore_thread_counts():
    """Monte Carlo flies single-threaded (montecarlo.single_threaded); give the other test
    modules of this process their thread counts back."""
    import cv2
    import numba

    cv2_threads, numba_threads = cv2.getNumThreads(), numba.get_num_threads()
    yield
    cv2.setNumThreads(cv2_threads)
    numba.set_num_threads(numba_threads)


def _comparable(verdict) -> dict:
    fields = dataclasses.asdict(verdict)
    fields.pop("wall_time_s")  # the only field that depends on the machine
    return fields


@pytest.mark.slow
def test_twenty_seeds_on_a_two_worker_cluster_match_the_single_process_run(tmp_path, capsys):
    alone = {s: _comparable(fly_seed(s, "mixed", "stereo", HORIZON_S)) for s in SEEDS}
    records: list[dict] = []
    with dask_client(n_workers=2) as client:
        fly_on_cluster(
            client,
            SEEDS,
            family="mixed",
            perception="stereo",
            max_time_s=HORIZON_S,
            on_record=records.append,
        )
    assert sorted(r["seed"] for r in records) == list(SEEDS)
    assert len({r["worker"] for r in records}) == 2, "both workers flew scenes"
    for record in records:
        assert record["failure"] != "error", record
        assert _comparable(verdict_from_record(record)) == alone[record["seed"]], record
    # and `stereo-avoid replay SEED` flies the same (the CLI, with its figures)
    seed = SEEDS[3]
    status = main(
        ["replay", str(seed), "--max-time-s", str(HORIZON_S), "--json", "--out", str(tmp_path)]
    )
    replayed = json.loads(capsys.readouterr().out)
    replayed.pop("wall_time_s")
    assert {k: replayed[k] for k in alone[seed]} == alone[seed]
    assert status == (0 if alone[seed]["reached_goal"] else 1)


def test_replay_dispatches_on_an_integer_seed(capsys):
    assert main(["replay", "flight"]) == 2
    assert "neither a seed" in capsys.readouterr().err
    # a .mcap is a companion recording (issue 15), not a seed: a missing one is refused
    assert main(["replay", "missing-flight.mcap"]) == 2
    assert "cannot open recording" in capsys.readouterr().err


def _lines(path: Path) -> list[dict]:
    """Complete lines only (a killed writer may leave a torn last one)."""
    text = path.read_text()
    return [json.loads(line) for line in text[: text.rfind("\n") + 1].splitlines()]


@pytest.mark.slow
def test_a_killed_batch_resumes_without_flying_a_finished_seed_again(tmp_path):
    out = tmp_path / "mc"
    cmd = [
        sys.executable,
        "-m",
        "evaluation.cli",
        "montecarlo",
        "--n",
        "10",
        "--seed",
        "200",
        "--jobs",
        "1",
        "--perception",
        "truth",
        "--max-time-s",
        "2",
        "--out",
        str(out),
    ]
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    log_path = tmp_path / "first.log"
    with log_path.open("w") as log:
        first = subprocess.Popen(
            cmd, stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True
        )
    results = out / "results.jsonl"
    deadline = time.monotonic() + 120.0
    try:
        while time.monotonic() < deadline and first.poll() is None:
            if results.exists() and len(results.read_text().splitlines()) >= 3:
                break
            time.sleep(0.05)
        assert first.poll() is None, f"ended before the kill:\n{log_path.read_text()}"
        assert results.exists(), f"no scene finished within 120 s:\n{log_path.read_text()}"
    finally:
        os.killpg(first.pid, signal.SIGKILL)  # the CLI, its scheduler and its workers
        first.wait(timeout=30)
    before = {r["seed"] for r in _lines(results)}
    assert 3 <= len(before) < 10, log_path.read_text()
    second = subprocess.run(
        [*cmd, "--resume"], capture_output=True, text=True, env=env, timeout=180
    )
    assert second.returncode in (0, 1), second.stdout + second.stderr
    assert f"{len(before)} already in" in second.stdout, second.stdout
    seeds = [r["seed"] for r in _lines(results)]
    assert sorted(seeds) == list(range(200, 210)), "every seed exactly once"
    assert set(seeds[: len(before)]) == before, "the finished seeds were kept, not flown again"
    for name in (
        "summary.txt",
        "summary.json",
        "min_separation_hist.png",
        "failures_by_cause.png",
        "failing_scenes.png",
    ):
        assert (out / name).is_file(), name


def test_results_file_refuses_to_mix_batches_and_cuts_a_torn_last_line(tmp_path):
    spec = BatchSpec(first_seed=0, n=3, family="mixed", perception="truth")
    verdict = fly_seed(0, "mixed", "truth", 0.1)
    record = {**dataclasses.asdict(verdict), "perception": "truth", "worker": "w"}
    with ResultsFile(tmp_path, spec) as results:
        results.append(record)
        with pytest.raises(ResultsFileError, match="already"):
            results.append(record)
    with pytest.raises(ResultsFileError, match="--resume"):
        ResultsFile(tmp_path, spec)
    with pytest.raises(ResultsFileError, match="another batch"):
        ResultsFile(tmp_path, dataclasses.replace(spec, perception="stereo"), resume=True)
    # a writer killed mid-line: the torn line is cut, its seed flown again
    with (tmp_path / "results.jsonl").open("a") as fh:
        fh.write('{"seed": 1, "scene": "path-1", "reach')
    resumed = ResultsFile(tmp_path, spec, resume=True)
    assert list(resumed.records) == [0]
    assert resumed.pending == [1, 2]
    assert (tmp_path / "results.jsonl").read_text().count("\n") == 1
    assert resumed.verdicts() == [verdict]


def test_a_resume_refuses_seeds_flown_by_other_code(tmp_path):
    """Every record names the code that flew it; resuming over seeds of other code (or of
    code that did not say) is refused unless asked for, and the counts show the mix."""
    spec = BatchSpec(first_seed=0, n=3, family="mixed", perception="truth")
    verdict = fly_seed(0, "mixed", "truth", 0.1)
    base = {**dataclasses.asdict(verdict), "perception": "truth", "worker": "w"}
    with ResultsFile(tmp_path, spec, code="aaaa") as results:
        results.append({**base, "code": "aaaa"})
        results.append({**base, "seed": 1, "code": "bbbb"})
        results.append({**base, "seed": 2})  # written before records carried their code
    assert list(ResultsFile(tmp_path, spec, resume=True).records) == [0, 1, 2]  # unchecked
    with pytest.raises(ResultsFileError, match=r"1 by bbbb, 1 by unknown\); this code is aaaa"):
        ResultsFile(tmp_path, spec, resume=True, code="aaaa")
    mixed = ResultsFile(tmp_path, spec, resume=True, code="aaaa", allow_code_change=True)
    assert code_counts(mixed.records.values()) == {"aaaa": 1, "bbbb": 1, "unknown": 1}


def test_the_code_fingerprint_follows_every_source_byte_and_nothing_else(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "sub" / "__pycache__").mkdir(parents=True)
    (pkg / "a.py").write_text("x = 1\n")
    (pkg / "sub" / "b.py").write_text("y = 2\n")
    first = source_fingerprint([pkg])
    assert len(first) == 16 and int(first, 16) >= 0
    (pkg / "sub" / "__pycache__" / "b.cpython-311.pyc").write_bytes(b"compiled")
    (pkg / "notes.txt").write_text("not source")
    assert source_fingerprint([pkg]) == first
    (pkg / "sub" / "b.py").write_text("y = 2  # a comment moves it too\n")
    assert source_fingerprint([pkg]) != first
    (pkg / "sub" / "b.py").write_text("y = 2\n")
    assert source_fingerprint([pkg]) == first
    (pkg / "sub" / "b.py").rename(pkg / "b.py")  # same bytes, another module
    assert source_fingerprint([pkg]) != first
    # the installed packages: stable within a process, the one fly_record stamps
    assert code_fingerprint() == code_fingerprint()
    assert fly_record(0, "mixed", "truth", 0.1)["code"] == code_fingerprint()


def test_the_cli_refuses_a_resume_over_other_code_and_a_stray_override(tmp_path, capsys):
    out = tmp_path / "mc"
    spec = BatchSpec(first_seed=0, n=2, family="mixed", perception="truth")
    verdict = fly_seed(0, "mixed", "truth", 0.1)
    with ResultsFile(out, spec) as results:
        results.append({**dataclasses.asdict(verdict), "worker": "w", "code": "bbbb"})
    args = ["montecarlo", "--n", "2", "--seed", "0", "--perception", "truth", "--out", str(out)]
    assert main([*args, "--resume"]) == 2
    err = capsys.readouterr().err
    assert "1 by bbbb" in err and f"this code is {code_fingerprint()}" in err, err
    assert main([*args, "--allow-code-change"]) == 2
    assert "only applies with --resume" in capsys.readouterr().err
    assert [r["code"] for r in _lines(out / "results.jsonl")] == ["bbbb"], "nothing flown"


def test_a_record_from_before_overspeed_frames_still_loads_and_a_missing_field_is_refused():
    """Verdict.overspeed_frames (issue 31) came later: older results files still resume."""
    record = verdict_to_record(error_verdict(7, "x"))
    del record["overspeed_frames"]
    assert verdict_from_record(record).overspeed_frames == 0
    del record["min_surface_distance_m"]
    with pytest.raises(ValueError, match="min_surface_distance_m"):
        verdict_from_record(record)
