"""``stereo-avoid sil``: plant-sim and the companion as two processes on loopback.

Starts ``python -m companion`` (Zenoh listening, MAVLink ``udpout`` to the plant) and
``python -m plant_sim`` (MAVLink ``udpin``, Zenoh connecting to the companion) on free
ports of 127.0.0.1 with multicast scouting off, waits for both readiness lines, shows
progress, stops both with SIGTERM when the companion reports the goal (or a timeout), and
judges the run from plant-sim's ground-truth log (``truth.csv``) with the same
:class:`~evaluation.harness.Verdict` and figures as the lockstep run.

The run is judged from the moment the companion sent its first setpoint (the plant hovers
while the companion connects), so ``sim_time_s`` is comparable with the lockstep run's.
No companion code is imported: the two talk only through MAVLink and Zenoh.
"""

from __future__ import annotations

import contextlib
import csv
import json
import math
import os
import queue
import random
import re
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from evaluation.harness import HOLD_REST_S, HOLD_REST_SPEED_MPS, RunConfig, Verdict
from evaluation.history import History
from evaluation.starve import Starvation, starve
from plant_sim.scenario import Scenario, load_scenario, paper_scenario

__all__ = [
    "ChildProcess",
    "SilOptions",
    "SilResult",
    "free_port",
    "history_from_truth",
    "run_sil",
    "settled_in_hold",
    "verdict_from_truth",
]

REPO = Path(__file__).resolve().parents[2]


#: where test and SIL ports are drawn from when the OS does not say its ephemeral range
_FALLBACK_EPHEMERAL = (32768, 60999)
_LOWEST_PORT = 20000


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    """A port free on 127.0.0.1 for both TCP and UDP, drawn at random *below* the OS's
    ephemeral range.

    Asking the OS for port 0 hands out the next ephemeral port, which the kernel may give to
    the very next outgoing socket (a child's ``udpout`` or Zenoh connection) or to a
    parallel test run before our child binds it: the "address already in use" race seen
    between xdist workers. Ports below the ephemeral range are never handed out
    implicitly, and a random draw makes two concurrent runs collide only by chance
    (~ one in ten thousand per pair of ports). ``kind`` is kept for callers; the port is
    checked free for both kinds.
    """
    low, high = _LOWEST_PORT, _ephemeral_range()[0] - 1
    rng = random.SystemRandom()
    for _ in range(200):
        port = rng.randint(low, high)
        if _bindable(port, socket.SOCK_STREAM) and _bindable(port, socket.SOCK_DGRAM):
            return port
    raise RuntimeError(f"no free port on 127.0.0.1 in {low}-{high} after 200 draws")


def _ephemeral_range() -> tuple[int, int]:
    try:
        text = Path("/proc/sys/net/ipv4/ip_local_port_range").read_text(encoding="ascii")
        low, high = (int(v) for v in text.split())
    except (OSError, ValueError):
        return _FALLBACK_EPHEMERAL
    return (low, high) if low > _LOWEST_PORT + 1000 else _FALLBACK_EPHEMERAL


def _bindable(port: int, kind: int) -> bool:
    with socket.socket(socket.AF_INET, kind) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


class ChildProcess:
    """``python -m <module> args`` with stdout lines queued and stderr kept in a file."""

    def __init__(self, name: str, module: str, args: Sequence[str], env: dict | None = None):
        self.name = name
        self._stderr = tempfile.TemporaryFile(mode="w+")  # noqa: SIM115 (closed in close())
        full_env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", **(env or {})}
        self.proc = subprocess.Popen(
            [sys.executable, "-m", module, *args],  # in the caller's working directory
            stdout=subprocess.PIPE,
            stderr=self._stderr,
            text=True,
            env=full_env,
        )
        self.lines: queue.Queue[str] = queue.Queue()
        self.stdout_lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            line = line.rstrip("\n")
            self.stdout_lines.append(line)
            self.lines.put(line)

    def wait_line(self, pattern: str, timeout_s: float) -> re.Match:
        """The next stdout line matching ``pattern`` (regex), within ``timeout_s``."""
        rx = re.compile(pattern)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            try:
                line = self.lines.get(timeout=0.1)
            except queue.Empty:
                if self.proc.poll() is not None and self.lines.empty():
                    raise RuntimeError(
                        f"{self.name} exited ({self.proc.returncode}) while waiting for "
                        f"{pattern!r}\n{self.logs()}"
                    ) from None
                continue
            m = rx.search(line)
            if m:
                return m
        raise TimeoutError(f"{self.name}: no line {pattern!r} within {timeout_s} s\n{self.logs()}")

    def events(self, name: str | None = None) -> list[tuple[str, dict]]:
        """``COMPANION EVENT`` lines seen so far as (name, fields)."""
        out = []
        for line in list(self.stdout_lines):
            if line.startswith("COMPANION EVENT "):
                _, _, ev, payload = line.split(" ", 3)
                if name is None or ev == name:
                    out.append((ev, json.loads(payload)))
        return out

    def stats(self, prefix: str) -> dict | None:
        for line in self.stdout_lines:
            if line.startswith(prefix):
                return json.loads(line[len(prefix) :])
        return None

    def stop(self, timeout_s: float = 15.0) -> int | None:
        """SIGTERM, wait; SIGKILL if it does not stop. Returns the exit status."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=5)
        self._reader.join(timeout=5)
        return self.proc.returncode

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=5)

    def stderr_text(self) -> str:
        self._stderr.seek(0)
        return self._stderr.read()

    def logs(self, tail_chars: int = 8000) -> str:
        return (
            f"--- {self.name} stdout ---\n"
            + "\n".join(self.stdout_lines[-200:])
            + f"\n--- {self.name} stderr ---\n"
            + self.stderr_text()[-tail_chars:]
        )

    def close(self) -> None:
        self.kill()
        self._reader.join(timeout=5)
        if self.proc.stdout is not None:
            self.proc.stdout.close()
        with contextlib.suppress(OSError):
            self._stderr.close()


# ---- judging from the ground truth -------------------------------------------------


def _read_truth(path: Path) -> dict[str, np.ndarray]:
    """The truth log's columns (empty cells NaN); a last row still being written (no
    newline yet: plant-sim is running) is left out."""
    with Path(path).open(newline="") as fh:
        text = fh.read()
    if not text.endswith("\n"):
        text = text[: text.rfind("\n") + 1]
    rows = list(csv.DictReader(text.splitlines()))
    cols: dict[str, np.ndarray] = {}
    if not rows:
        return cols
    for key in rows[0]:
        if key == "mode":
            continue
        cols[key] = np.array([float(r[key]) if r[key] != "" else math.nan for r in rows])
    return cols


def _avoid_intervals(events: list[tuple[str, dict]]) -> list[tuple[float, float]]:
    intervals, start = [], None
    for name, fields in events:
        if name != "avoidance":
            continue
        if fields.get("active") and start is None:
            start = float(fields["capture_s"])
        elif not fields.get("active") and start is not None:
            intervals.append((start, float(fields["capture_s"])))
            start = None
    if start is not None:
        intervals.append((start, math.inf))
    return intervals


def _hold_intervals(events: list[tuple[str, dict]]) -> list[tuple[float, float, str]]:
    """Guidance's reported holds ``(start_s, end_s, reason)`` on the frames' clock, from the
    companion's ``hold`` / ``hold_end`` events (a failsafe hold, which has no capture time,
    is not a guidance stop). An open hold ends at ``inf``."""
    intervals: list[tuple[float, float, str]] = []
    start: tuple[float, str] | None = None
    for name, fields in events:
        if name == "hold" and "capture_s" in fields:
            if start is not None:  # a new reason while holding: the hold goes on
                intervals.append((start[0], float(fields["capture_s"]), start[1]))
            start = (float(fields["capture_s"]), str(fields.get("reason")))
        elif name == "hold_end" and start is not None:
            intervals.append((start[0], float(fields["capture_s"]), start[1]))
            start = None
    if start is not None:
        intervals.append((start[0], math.inf, start[1]))
    return intervals


def _rest_in_hold(
    t: np.ndarray, speed_mps: np.ndarray, holds: Sequence[tuple[float, float, str]]
) -> tuple[int, str] | None:
    """(sample, reason) at which the vehicle has been slower than HOLD_REST_SPEED_MPS for
    HOLD_REST_S inside one reported hold: where the lockstep harness ends a run in a stop."""
    for start_s, end_s, reason in holds:
        rest_since = None
        for i in np.flatnonzero((t >= start_s) & (t < end_s)):
            if not speed_mps[i] < HOLD_REST_SPEED_MPS:
                rest_since = None
                continue
            rest_since = t[i] if rest_since is None else rest_since
            if t[i] - rest_since >= HOLD_REST_S:
                return int(i), reason
    return None


def settled_in_hold(truth_path: Path, events: list[tuple[str, dict]]) -> bool:
    """True once the truth log shows the vehicle at rest in a hold guidance reported."""
    holds = _hold_intervals(events)
    if not holds or not Path(truth_path).is_file():
        return False
    truth = _read_truth(truth_path)
    if not truth:
        return False
    return _rest_in_hold(truth["time_s"], _speed(truth), holds) is not None


def _speed(truth: dict[str, np.ndarray]) -> np.ndarray:
    return np.sqrt(sum(truth[k] ** 2 for k in ("vel_n_mps", "vel_e_mps", "vel_d_mps")))


def _max_abs_deg(angles_rad: np.ndarray) -> float:
    """Largest |angle| [deg] ignoring empty cells (an external autopilot may not say what
    it commanded: NaN when no sample has it)."""
    finite = np.abs(angles_rad[np.isfinite(angles_rad)])
    return round(math.degrees(float(np.max(finite))), 4) if finite.size else math.nan


def verdict_from_truth(
    truth: dict[str, np.ndarray],
    *,
    scene: str,
    goal_ned_m,
    t0_s: float,
    avoid_intervals: list[tuple[float, float]],
    frames: int,
    wall_time_s: float,
    config: RunConfig | None = None,
    hold_intervals: Sequence[tuple[float, float, str]] = (),
) -> Verdict:
    """The lockstep :class:`Verdict`, computed from plant-sim's truth log after ``t0_s``.

    The run ends at the first of: a collision (centre nearer a surface than
    ``collision_distance_m``), a sample within the goal tolerance, the vehicle at rest in a
    hold guidance reported (``hold_intervals``, :func:`_hold_intervals`; the lockstep rule:
    slower than HOLD_REST_SPEED_MPS for HOLD_REST_S), or the end of the log (a timeout).
    """
    cfg = config or RunConfig()
    t = truth["time_s"]
    sel = t >= t0_s - 1e-9
    t = t[sel]
    pos = np.stack([truth[k][sel] for k in ("pos_n_m", "pos_e_m", "pos_d_m")], axis=1)
    surface = truth["surface_distance_m"][sel]
    surface = np.where(np.isnan(surface), math.inf, surface)
    goal_dist = np.linalg.norm(pos - np.asarray(goal_ned_m, dtype=float), axis=1)
    end = len(t) - 1
    reached = collided = False
    failure: str | None = None
    hold_reason: str | None = None
    hit_goal = np.flatnonzero(goal_dist < cfg.goal_tolerance_m)
    hit_obst = np.flatnonzero(surface < cfg.collision_distance_m)
    rest = _rest_in_hold(t, _speed(truth)[sel], hold_intervals)
    first = {
        "collision": int(hit_obst[0]) if hit_obst.size else math.inf,
        "goal": int(hit_goal[0]) if hit_goal.size else math.inf,
        "hold": rest[0] if rest is not None else math.inf,
    }
    how = min(first, key=first.get)  # ties: collision, then goal, then hold
    if first[how] == math.inf:
        failure = "timeout"
    elif how == "collision":
        end, collided, failure = int(first[how]), True, "collision"
    elif how == "goal":
        end, reached = int(first[how]), True
    else:
        end, failure, hold_reason = int(first[how]), "hold", rest[1]
    w = slice(0, end + 1)
    t_end = float(t[end])
    avoid = sum(max(0.0, min(b, t_end) - max(a, t0_s)) for a, b in avoid_intervals)
    return Verdict(
        scene=scene,
        seed=0,
        reached_goal=reached,
        collided=collided,
        min_surface_distance_m=round(float(np.min(surface[w])), 4),
        max_roll_cmd_deg=_max_abs_deg(truth["roll_cmd_rad"][sel][w]),
        max_pitch_cmd_deg=_max_abs_deg(truth["pitch_cmd_rad"][sel][w]),
        avoidance_time_s=round(avoid, 4),
        sim_time_s=round(t_end - t0_s, 4),
        wall_time_s=round(wall_time_s, 3),
        final_goal_distance_m=round(float(goal_dist[end]), 4),
        frames=frames,
        failure=failure,
        hold_reason=hold_reason,
    )


def history_from_truth(
    truth: dict[str, np.ndarray], t0_s: float, avoid_intervals: list[tuple[float, float]]
) -> History:
    """A lockstep :class:`History` from the truth log (time shifted so that t0 = 0).

    The truth log has no setpoints, obstacle counts or envelope figures (the companion's
    business): those columns are NaN.
    """
    h = History()
    t_all = truth["time_s"]
    for i in np.flatnonzero(t_all >= t0_s - 1e-9):
        ts = float(t_all[i])
        avoid = any(a <= ts < b for a, b in avoid_intervals)
        h.append(
            time_s=ts - t0_s,
            north_m=truth["pos_n_m"][i],
            east_m=truth["pos_e_m"][i],
            down_m=truth["pos_d_m"][i],
            vn_mps=truth["vel_n_mps"][i],
            ve_mps=truth["vel_e_mps"][i],
            vd_mps=truth["vel_d_mps"][i],
            roll_deg=math.degrees(truth["roll_rad"][i]),
            pitch_deg=math.degrees(truth["pitch_rad"][i]),
            yaw_deg=math.degrees(truth["yaw_rad"][i]),
            roll_cmd_deg=math.degrees(truth["roll_cmd_rad"][i]),
            pitch_cmd_deg=math.degrees(truth["pitch_cmd_rad"][i]),
            yaw_cmd_deg=math.degrees(truth["yaw_cmd_rad"][i]),
            rotor1_n=truth["rotor1_n"][i],
            rotor2_n=truth["rotor2_n"][i],
            rotor3_n=truth["rotor3_n"][i],
            rotor4_n=truth["rotor4_n"][i],
            nearest_surface_m=truth["surface_distance_m"][i],
            avoid_flag=1.0 if avoid else 0.0,
            mode=math.nan,
            setpoint_north_m=math.nan,
            setpoint_east_m=math.nan,
            setpoint_down_m=math.nan,
            n_obstacles_seen=math.nan,
            tilt_saturated=truth["tilt_saturated"][i],
            free_distance_m=math.nan,
            speed_limit_mps=math.nan,
            speed_mps=math.hypot(
                truth["vel_n_mps"][i], truth["vel_e_mps"][i], truth["vel_d_mps"][i]
            ),
        )
    return h


# ---- the run -----------------------------------------------------------------------


@dataclass(frozen=True)
class SilOptions:
    """How a SIL run is set up."""

    scenario_path: Path | None = None  # None: the paper's §6
    speedup: float = 4.0
    out_dir: Path = Path("runs/sil")
    max_time_s: float = 90.0  # simulation time after the companion starts steering
    signing_key: str | None = None  # shared key given to both processes (environment)
    companion_args: tuple[str, ...] = ()
    plant_args: tuple[str, ...] = ()
    startup_timeout_s: float = 60.0
    # the companion held to this fraction of one core (evaluation.starve); None: unlimited
    companion_core_fraction: float | None = None
    # end the run once the vehicle rests in a reported hold (False: fly on to max_time_s,
    # e.g. to watch a hold under a drifting estimate)
    end_at_rest: bool = True


@dataclass(frozen=True, eq=False)
class SilResult:
    verdict: Verdict
    history: History
    plant_stats: dict | None
    companion_stats: dict | None
    events: list[tuple[str, dict]] = field(default_factory=list)
    truth_path: Path | None = None
    starvation: str | None = None  # how the companion was starved, if it was


def run_sil(
    options: SilOptions,
    progress: Callable[[str], None] | None = None,
) -> SilResult:
    """Fly a scenario with both processes on loopback; judge it from the truth log."""
    say = progress or (lambda _text: None)
    scenario: Scenario = (
        load_scenario(options.scenario_path) if options.scenario_path else paper_scenario()
    )
    goal = scenario.goal_ned_m or (0.0, 0.0, -7.0)
    out = Path(options.out_dir).resolve()  # the children may run anywhere
    out.mkdir(parents=True, exist_ok=True)
    mav_port = free_port()
    zen = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    env = {"STEREO_AVOID_SIGNING_KEY": options.signing_key} if options.signing_key else {}
    companion = ChildProcess(
        "companion",
        "companion",
        [
            "--mavlink",
            f"udpout:127.0.0.1:{mav_port}",
            "--zenoh-listen",
            zen,
            "--vehicle-id",
            scenario.vehicle_id,
            "--goal",
            *(str(x) for x in goal),
            *options.companion_args,
        ],
        env,
    )
    plant: ChildProcess | None = None
    starved: Starvation | None = None
    wall_start = time.monotonic()
    try:
        if options.companion_core_fraction is not None:
            starved = starve(companion.proc.pid, options.companion_core_fraction)
            say(f"companion starved: {starved.describe()}")
        companion.wait_line(r"^COMPANION READY ", options.startup_timeout_s)
        plant = _start_plant(options, out, mav_port, zen, env)
        plant.wait_line(r"^PLANT_SIM READY ", options.startup_timeout_s)
        say(f"plant-sim and companion up (MAVLink udp {mav_port}, Zenoh {zen})")
        t0 = _fly(options, companion, plant, say, out / "truth.csv")
    finally:
        if plant is not None:
            plant.stop()
        companion.stop()
        if starved is not None:
            starved.close()
    result = _collect(options, out, goal, companion, plant, t0, time.monotonic() - wall_start)
    return replace(result, starvation=None if starved is None else starved.describe())


def _start_plant(
    options: SilOptions, out: Path, mav_port: int, zen: str, env: dict[str, str]
) -> ChildProcess:
    """plant-sim connected to the companion's MAVLink port and Zenoh endpoint."""
    plant_cmd = [
        "--mavlink",
        f"udpin:127.0.0.1:{mav_port}",
        "--zenoh-connect",
        zen,
        "--zenoh-listen",
        f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}",
        "--speedup",
        f"{options.speedup:g}",
        "--log-dir",
        str(out),
        *options.plant_args,
    ]
    if options.scenario_path:
        plant_cmd += ["--scenario", str(options.scenario_path)]
    return ChildProcess("plant-sim", "plant_sim", plant_cmd, env)


def _fly(
    options: SilOptions,
    companion: ChildProcess,
    plant: ChildProcess,
    say: Callable[[str], None],
    truth_path: Path,
) -> float:
    """Wait for the companion to steer, then for the goal, a reported hold come to rest
    (:func:`settled_in_hold`), plant-sim's end or the time limit, saying the companion's
    progress once a second; the steering time [s, sim]."""
    steering = companion.wait_line(r"^COMPANION EVENT steering ", 30.0)
    t0 = json.loads(steering.string.split(" ", 3)[3]).get("autopilot_time_s") or 0.0
    say(f"companion steering at t={t0:.2f} s (simulation time)")
    deadline = time.monotonic() + options.max_time_s / options.speedup + 10.0
    last_say = 0.0
    while time.monotonic() < deadline:
        if companion.events("goal_reached") or plant.proc.poll() is not None:
            break
        if companion.proc.poll() is not None:
            raise RuntimeError(f"companion exited\n{companion.logs()}")
        if time.monotonic() - last_say >= 1.0:
            last_say = time.monotonic()
            last = _last_progress(companion.stderr_text())
            if last:
                say(last)
            if options.end_at_rest and settled_in_hold(truth_path, companion.events()):
                say("stopped in a reported hold")
                break
        time.sleep(0.05)
    time.sleep(0.5)  # a little of the flight after the goal, as the truth log samples it
    return t0


def _collect(
    options: SilOptions,
    out: Path,
    goal,
    companion: ChildProcess,
    plant: ChildProcess | None,
    t0: float,
    wall_s: float,
) -> SilResult:
    """The children's logs into ``out``, their statistics, and the verdict from the truth."""
    events = companion.events()
    companion_stats = companion.stats("COMPANION STATS ")
    plant_stats = plant.stats("PLANT_SIM STATS ") if plant is not None else None
    (out / "companion.log").write_text(companion.stderr_text())
    if plant is not None:
        (out / "plant_sim.log").write_text(plant.stderr_text())
        plant.close()
    companion.close()
    truth_path = out / "truth.csv"
    truth = _read_truth(truth_path)
    intervals = _avoid_intervals(events)
    verdict = verdict_from_truth(
        truth,
        scene=("paper" if options.scenario_path is None else options.scenario_path.stem),
        goal_ned_m=goal,
        t0_s=t0,
        avoid_intervals=intervals,
        frames=(companion_stats or {}).get("frames_processed", 0),
        wall_time_s=wall_s,
        hold_intervals=_hold_intervals(events),
    )
    return SilResult(
        verdict=verdict,
        history=history_from_truth(truth, t0, intervals),
        plant_stats=plant_stats,
        companion_stats=companion_stats,
        events=events,
        truth_path=truth_path,
    )


_PROGRESS = re.compile(r"companion: (t=\S+ pos=\([^)]*\) phase=\S+ mode=\S+ health=\S+)")


def _last_progress(stderr_text: str) -> str | None:
    found = _PROGRESS.findall(stderr_text[-4000:])
    return found[-1] if found else None
