"""Monte Carlo results on disk: one JSON line per finished seed, appended as it finishes.

An output folder holds ``run.json`` (the batch's :class:`BatchSpec`: which seeds, which
scene family, which perception) and ``results.jsonl`` (one :class:`Verdict` per line, in
the order the scenes finished, with the worker that flew it). Every line is flushed when
written, so a killed run loses at most the scene in flight; ``--resume`` reads the file
back, drops a torn last line, and flies only the seeds not in it. A folder is never mixed
between batches: resuming with another spec is an error, and so is resuming seeds flown by
other code (each record's ``code``, :mod:`evaluation.mc_provenance`) unless
``allow_code_change`` says the mix is wanted.
"""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from evaluation.harness import Verdict
from evaluation.mc_provenance import code_counts

__all__ = [
    "PERCEPTIONS",
    "RESULTS_NAME",
    "SPEC_NAME",
    "BatchSpec",
    "ResultsFile",
    "ResultsFileError",
    "verdict_from_record",
    "verdict_to_record",
]

RESULTS_NAME = "results.jsonl"
SPEC_NAME = "run.json"
PERCEPTIONS: tuple[str, ...] = ("stereo", "truth", "depth")
_VERDICT_FIELDS = tuple(f.name for f in dataclasses.fields(Verdict))
_VERDICT_DEFAULTS = {
    f.name: f.default
    for f in dataclasses.fields(Verdict)
    if f.default is not dataclasses.MISSING and f.name != "hold_reason"
}


class ResultsFileError(RuntimeError):
    """An output folder that cannot be written or resumed (says which file and why)."""


@dataclass(frozen=True)
class BatchSpec:
    """What a Monte Carlo batch flies: seeds ``first_seed … first_seed + n − 1``."""

    first_seed: int
    n: int
    family: str = "mixed"
    perception: str = "stereo"  # one of PERCEPTIONS
    max_time_s: float | None = None  # simulation time limit per scene; None: RunConfig's

    def __post_init__(self) -> None:
        if self.n < 1:
            raise ValueError(f"n must be >= 1, got {self.n}")
        if self.perception not in PERCEPTIONS:
            raise ValueError(f"perception must be one of {PERCEPTIONS}, got {self.perception!r}")
        if self.max_time_s is not None and not self.max_time_s > 0:
            raise ValueError(f"max_time_s must be positive, got {self.max_time_s!r}")

    @property
    def seeds(self) -> range:
        """The seeds of the batch, in order."""
        return range(self.first_seed, self.first_seed + self.n)


def verdict_to_record(verdict: Verdict, **extra: Any) -> dict[str, Any]:
    """A verdict as a JSON-ready dict, plus ``extra`` keys (worker, perception...)."""
    return {**dataclasses.asdict(verdict), **extra}


def verdict_from_record(record: dict[str, Any]) -> Verdict:
    """The :class:`Verdict` of a record written by :func:`verdict_to_record`."""
    missing = [f for f in _VERDICT_FIELDS if f not in record and f not in _VERDICT_DEFAULTS]
    if missing:
        raise ValueError(f"verdict record lacks {missing}")
    # a field added later with a default (overspeed_frames) is absent from older records
    return Verdict(**{f: record.get(f, _VERDICT_DEFAULTS.get(f)) for f in _VERDICT_FIELDS})


class ResultsFile:
    """``run.json`` + ``results.jsonl`` in ``out_dir`` (module docstring).

    Parameters
    ----------
    out_dir : path
        Output folder (created if needed).
    spec : BatchSpec
        The batch; written to ``run.json`` or, with ``resume``, checked against it.
    resume : bool
        Keep the seeds already in ``results.jsonl``. Without it, a folder that already
        holds results is an error (nothing is overwritten).
    code : str or None
        Fingerprint of the code that will fly the remaining seeds; with ``resume``, seeds
        already flown by other code (or by code that did not say) are an error, unless
        ``allow_code_change``. ``None``: not checked.
    allow_code_change : bool
        Finish a batch started by other code (the report lists each fingerprint's seeds).
    """

    def __init__(
        self,
        out_dir: Path,
        spec: BatchSpec,
        *,
        resume: bool = False,
        code: str | None = None,
        allow_code_change: bool = False,
    ) -> None:
        self.out_dir = Path(out_dir)
        self.spec = spec
        self.path = self.out_dir / RESULTS_NAME
        self.spec_path = self.out_dir / SPEC_NAME
        self.records: dict[int, dict[str, Any]] = {}
        self.out_dir.mkdir(parents=True, exist_ok=True)
        if self.spec_path.exists() or self.path.exists():
            if not resume:
                raise ResultsFileError(
                    f"{self.out_dir} already holds a Monte Carlo run; pass --resume to "
                    "finish it or choose another --out"
                )
            self._check_spec()
            self.records = self._read()
            if code is not None and not allow_code_change:
                self._check_code(code)
        self.spec_path.write_text(json.dumps(dataclasses.asdict(spec), indent=2) + "\n")
        self._fh: IO[str] | None = None

    @property
    def pending(self) -> list[int]:
        """Seeds of the batch not yet in the file, in order."""
        return [s for s in self.spec.seeds if s not in self.records]

    def append(self, record: dict[str, Any]) -> None:
        """Write one finished seed's record (flushed at once)."""
        seed = int(record["seed"])
        if seed in self.records:
            raise ResultsFileError(f"seed {seed} is already in {self.path}")
        if self._fh is None:
            self._fh = self.path.open("a", encoding="utf-8")
        self._fh.write(json.dumps(record, allow_nan=True) + "\n")
        self._fh.flush()
        os.fsync(self._fh.fileno())
        self.records[seed] = record

    def close(self) -> None:
        """Close the results file (records stay readable in :attr:`records`)."""
        if self._fh is not None:
            self._fh.close()
            self._fh = None

    def __enter__(self) -> ResultsFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def verdicts(self) -> list[Verdict]:
        """The finished seeds' verdicts, in seed order."""
        return [verdict_from_record(self.records[s]) for s in sorted(self.records)]

    def _check_spec(self) -> None:
        try:
            have = BatchSpec(**json.loads(self.spec_path.read_text()))
        except (OSError, ValueError, TypeError) as exc:
            raise ResultsFileError(f"cannot read {self.spec_path}: {exc}") from exc
        if have != self.spec:
            raise ResultsFileError(
                f"{self.out_dir} holds another batch ({have}); --resume needs the same "
                f"--seed, --n, --family, --perception and --max-time-s ({self.spec})"
            )

    def _check_code(self, code: str) -> None:
        others = {c: n for c, n in code_counts(self.records.values()).items() if c != code}
        if others:
            flown = ", ".join(f"{n} by {c}" for c, n in others.items())
            raise ResultsFileError(
                f"{self.path} holds seeds flown by other code ({flown}); this code is {code}. "
                "Finish the batch with the code that started it, start a new --out, or pass "
                "--allow-code-change to mix them (the report lists which code flew which seeds)"
            )

    def _read(self) -> dict[int, dict[str, Any]]:
        """Records already on disk; a torn last line (a killed writer) is cut off."""
        if not self.path.exists():
            return {}
        raw = self.path.read_bytes()
        lines = raw.split(b"\n")
        records: dict[int, dict[str, Any]] = {}
        good_bytes = 0
        for i, line in enumerate(lines):
            if not line.strip():
                good_bytes += len(line) + (1 if i < len(lines) - 1 else 0)
                continue
            try:
                record = json.loads(line)
                verdict_from_record(record)
            except ValueError as exc:
                if i == len(lines) - 1:  # torn last line: the scene in flight is flown again
                    break
                raise ResultsFileError(f"{self.path} line {i + 1} is corrupt: {exc}") from exc
            seed = int(record["seed"])
            if seed in records:
                raise ResultsFileError(f"{self.path}: seed {seed} appears twice")
            if seed not in self.spec.seeds:
                raise ResultsFileError(f"{self.path}: seed {seed} is not in {self.spec}")
            records[seed] = record
            good_bytes += len(line) + 1
        if good_bytes < len(raw):
            with self.path.open("r+b") as fh:
                fh.truncate(good_bytes)
        return records
