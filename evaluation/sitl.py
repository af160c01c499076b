"""``stereo-avoid sil --autopilot arducopter-sitl``: the paper's scene on ArduPilot's own
ArduCopter SITL, with plant-sim as the camera only.

Three processes, all on 127.0.0.1, all stopped at the end:

* ``arducopter`` (ArduPilot SITL, from ``$ARDUCOPTER_SITL`` only: no binary ships with
  this project, a user builds one from ArduPilot's repository) in a fresh temporary folder
  (it writes ``eeprom.bin``, ``logs/``, ``terrain/`` into its working directory), on a free
  instance ``-I N``: SERIAL0 on TCP 5760+10N (the companion), SERIAL1 on 5762+10N
  (plant-sim), SERIAL2 on 5763+10N (free for a ground station), ``--speedup K``,
  parameters ``copter.parm`` then the extra file(s) (later files win);
* the companion: ``--takeoff-alt 7 --frame-clock autopilot --goal 20 0 -7``; it waits for
  the EKF origin, GPS and camera frames, switches to GUIDED, arms, takes off and steers
  (SITL boots at ``SIM_SPEEDUP`` ``boot_speedup``, set through SERIAL2, and is brought
  back to ``speedup`` when the takeoff starts);
* ``plant-sim --pose-from tcp:…:5762+10N``: renders the scene (a 1.5 m sphere 10 m north
  of home at 7 m) from SITL's pose and writes the ground truth.

The scene in SITL's LOCAL_NED (home = origin, SITL's default location and heading):
takeoff at home to 7 m, goal (20, 0, −7), sphere centre (10, 0, −7), radius 1.5 m. It is
the paper's §6 flown northwards from the ground. The run is judged from plant-sim's
``truth.csv`` from the companion's first setpoint on, exactly like ``stereo-avoid sil``.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import random
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from evaluation.sil import (
    ChildProcess,
    SilResult,
    _avoid_intervals,
    _hold_intervals,
    _last_progress,
    _read_truth,
    free_port,
    history_from_truth,
    settled_in_hold,
    verdict_from_truth,
)
from evaluation.sitl_scene import SitlScene, paper_sitl_scene

__all__ = [
    "ARDUCOPTER_SITL_ENV",
    "SITL_HOWTO",
    "ArduCopterSitl",
    "SitlOptions",
    "SitlRig",
    "find_arducopter_sitl",
    "free_sitl_instance",
    "run_sitl_sil",
    "speed_figures",
]

ARDUCOPTER_SITL_ENV = "ARDUCOPTER_SITL"

#: What every SITL entry point (tests, CLI, benchmark, Docker smoke test) says when
#: ``$ARDUCOPTER_SITL`` names no executable: where a binary comes from.
SITL_HOWTO = (
    f"no ArduCopter SITL binary: set ${ARDUCOPTER_SITL_ENV} to an ArduCopter SITL executable "
    "(build it from ArduPilot's repository as its documentation 'Setting up SITL on Linux' "
    "says: ./waf configure --board sitl && ./waf copter → build/sitl/bin/arducopter, with "
    "Tools/autotest/default_params/copter.parm copied beside it as copter.parm)"
)


def _die_with_parent_hook() -> Callable[[], None] | None:
    """A ``preexec_fn`` (Linux): the child gets SIGTERM when its parent dies, so a killed
    test run leaves no SITL behind on a shared machine. libc is looked up here, in the
    parent; the child only makes the one ``prctl`` call before exec."""
    if not sys.platform.startswith("linux"):
        return None
    import ctypes

    prctl = ctypes.CDLL(None, use_errno=True).prctl
    pr_set_pdeathsig, sigterm = 1, int(signal.SIGTERM)

    def hook() -> None:
        prctl(pr_set_pdeathsig, sigterm)

    return hook


def find_arducopter_sitl(environ: Mapping[str, str] | None = None) -> Path | None:
    """The ArduCopter SITL binary named by ``$ARDUCOPTER_SITL``; None when the variable is
    unset or names no executable file (then say :data:`SITL_HOWTO`). There is no other
    place it is looked for: the real autopilot is opt-in."""
    env = os.environ if environ is None else environ
    value = env.get(ARDUCOPTER_SITL_ENV, "")
    if not value:
        return None
    path = Path(value)
    if path.is_file() and os.access(path, os.X_OK):
        return path.resolve()
    return None


def _port_free(port: int, kind: int) -> bool:
    with socket.socket(socket.AF_INET, kind) as s:
        if kind == socket.SOCK_STREAM:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def free_sitl_instance(rng: random.Random | None = None, tries: int = 200) -> int:
    """An instance number N (SITL keeps it in 8 bits: 0..255) whose SITL ports are free:
    TCP 5760..5763 + 10N (serial ports), UDP 5501..5503 + 10N (simulator I/O) and
    9005 + 10N (IRLock)."""
    rng = rng or random.Random()
    for _ in range(tries):
        n = rng.randrange(20, 256)
        tcp = [5760 + 10 * n + k for k in range(4)]
        udp = [5501 + 10 * n + k for k in range(3)] + [9005 + 10 * n]
        if all(_port_free(p, socket.SOCK_STREAM) for p in tcp) and all(
            _port_free(p, socket.SOCK_DGRAM) for p in udp
        ):
            return n
    raise RuntimeError("no free ArduCopter SITL instance (ports 5760+10N) found")


class ArduCopterSitl:
    """One ``arducopter`` SITL process in its own temporary folder; output in ``sitl.log``.

    Parameters
    ----------
    binary : the ArduCopter SITL executable.
    defaults : parameter files, later ones win (``copter.parm`` first).
    instance : ``-I N``.
    speedup : ``--speedup K``.
    home : ``--home lat,lon,alt,yaw``; None: SITL's default site and heading.
    """

    def __init__(
        self,
        binary: Path,
        defaults: Sequence[Path],
        instance: int,
        speedup: float,
        home: str | None = None,
    ) -> None:
        self.binary = Path(binary)
        self.instance = instance
        self.speedup = speedup
        self.workdir = Path(tempfile.mkdtemp(prefix=f"arducopter-sitl-I{instance}-"))
        self.log_path = self.workdir / "sitl.log"
        self._log = self.log_path.open("w")
        self.proc = subprocess.Popen(
            [
                str(self.binary),
                "--model",
                "quad",
                "--speedup",
                f"{speedup:g}",
                "--defaults",
                ",".join(str(p) for p in defaults),
                "-I",
                str(instance),
                *(("--home", home) if home is not None else ()),
            ],
            cwd=self.workdir,
            stdin=subprocess.DEVNULL,
            stdout=self._log,
            stderr=subprocess.STDOUT,
            preexec_fn=_die_with_parent_hook(),
        )

    def port(self, serial: int) -> int:
        """TCP port of SERIAL0 (5760+10N), SERIAL1 (5762+10N) or SERIAL2 (5763+10N)."""
        return {0: 5760, 1: 5762, 2: 5763}[serial] + 10 * self.instance

    def url(self, serial: int) -> str:
        return f"tcp:127.0.0.1:{self.port(serial)}"

    def output(self) -> str:
        self._log.flush()
        try:
            return self.log_path.read_text(errors="replace")
        except OSError:
            return ""

    def wait_output(self, pattern: str, timeout_s: float) -> None:
        """Wait (bounded) until the SITL's output matches ``pattern``."""
        rx = re.compile(pattern)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if rx.search(self.output()):
                return
            if self.proc.poll() is not None:
                raise RuntimeError(
                    f"ArduCopter SITL exited ({self.proc.returncode}) while waiting for "
                    f"{pattern!r}\n{self.logs()}"
                )
            time.sleep(0.05)
        raise TimeoutError(f"ArduCopter SITL: no {pattern!r} within {timeout_s} s\n{self.logs()}")

    def logs(self, tail_chars: int = 4000) -> str:
        return f"--- arducopter SITL (-I{self.instance}) ---\n" + self.output()[-tail_chars:]

    def stop(self, timeout_s: float = 10.0) -> int | None:
        """SIGTERM, wait; SIGKILL if it does not stop."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=5)
        return self.proc.returncode

    def close(self) -> None:
        self.stop()
        self._log.close()
        shutil.rmtree(self.workdir, ignore_errors=True)


@dataclass(frozen=True)
class SitlOptions:
    """How an ArduCopter SITL run is set up."""

    binary: Path
    out_dir: Path = Path("runs/sitl")
    speedup: float = 5.0  # SITL --speedup
    # SIM_SPEEDUP while SITL boots (EKF origin, GPS: ~42 s of its time), back to
    # ``speedup`` when the companion starts its takeoff; 0: off. (MAVProxy's
    # sitl_autospeedup module does the same.)
    boot_speedup: float = 10.0
    params_files: tuple[Path, ...] = ()  # extra parameter files (after copter.parm)
    params: tuple[tuple[str, float], ...] = ()  # extra parameters (written to a file)
    scene: SitlScene = field(default_factory=paper_sitl_scene)  # what is flown, where
    scene_name: str = "paper-sitl"  # the verdict's scene name
    max_time_s: float = 120.0  # autopilot time after the companion starts steering
    startup_timeout_s: float = 240.0  # wall: boot, EKF/GPS, takeoff
    companion_args: tuple[str, ...] = ()
    plant_args: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not (math.isfinite(self.speedup) and self.speedup > 0):
            raise ValueError(f"SITL speedup must be > 0, got {self.speedup!r}")
        for name, value in self.params:
            if not re.fullmatch(r"[A-Z][A-Z0-9_]{0,15}", name) or not math.isfinite(value):
                raise ValueError(f"bad SITL parameter {name}={value!r}")


class SitlRig:
    """SITL + companion + camera-only plant-sim; :meth:`start`, :meth:`close` (always).

    Between them a caller waits for events (:meth:`wait_event`), opens a ground station
    on SERIAL2 (:meth:`gcs_url`) and finally :meth:`judge`\\s the run.
    """

    def __init__(self, options: SitlOptions, progress: Callable[[str], None] | None = None):
        self.options = options
        self.say = progress or (lambda _text: None)
        self.out = Path(options.out_dir).resolve()
        self.sitl: ArduCopterSitl | None = None
        self.companion: ChildProcess | None = None
        self.plant: ChildProcess | None = None
        self.t0_s: float | None = None  # autopilot time of the first setpoint
        self._wall_start = time.monotonic()
        self._closed = False

    # ---- lifecycle -----------------------------------------------------------------
    def start(self) -> None:
        """Start SITL, the companion and plant-sim (each waited for, bounded)."""
        o = self.options
        self.out.mkdir(parents=True, exist_ok=True)
        scenario = self.out / "scenario.json"
        scenario.write_text(json.dumps(o.scene.scenario, indent=2) + "\n")
        defaults = [Path(o.binary).parent / "copter.parm", *o.params_files]
        if o.params:
            extra = self.out / "extra.parm"
            extra.write_text("".join(f"{k} {v:g}\n" for k, v in o.params))
            defaults.append(extra)
        for path in defaults:
            if not path.is_file():
                raise OSError(f"SITL parameter file {path} not found")
        instance = free_sitl_instance()
        self.sitl = ArduCopterSitl(
            Path(o.binary), defaults, instance, o.speedup, o.scene.home_arg()
        )
        self.sitl.wait_output(r"Waiting for connection", 30.0)
        zen = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
        self.companion = ChildProcess(
            "companion",
            "companion",
            [
                "--mavlink",
                self.sitl.url(0),
                "--zenoh-listen",
                zen,
                "--vehicle-id",
                "sim1",
                "--goal",
                *(f"{x:g}" for x in o.scene.goal_ned_m),
                "--takeoff-alt",
                f"{o.scene.takeoff_alt_m:g}",
                "--frame-clock",
                "autopilot",
                *o.companion_args,
            ],
        )
        self.companion.wait_line(r"^COMPANION READY ", 60.0)
        self.sitl.wait_output(r"SERIAL1 on TCP port", 30.0)
        self.plant = ChildProcess(
            "plant-sim",
            "plant_sim",
            [
                "--pose-from",
                self.sitl.url(1),
                "--scenario",
                str(scenario),
                "--zenoh-connect",
                zen,
                "--zenoh-listen",
                f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}",
                "--log-dir",
                str(self.out),
                *o.plant_args,
            ],
        )
        self.plant.wait_line(r"^PLANT_SIM READY ", 60.0)
        if o.boot_speedup > o.speedup:
            self._set_sim_speedup(o.boot_speedup)
        self.say(
            f"ArduCopter SITL -I{instance} at {o.speedup:g}x (companion on "
            f"{self.sitl.url(0)}, plant-sim camera-only on {self.sitl.url(1)})"
        )

    def _set_sim_speedup(self, speedup: float, timeout_s: float = 10.0) -> None:
        """PARAM_SET SIM_SPEEDUP through SERIAL2 (connect, confirm by PARAM_VALUE, close)."""
        from pymavlink import mavutil

        assert self.sitl is not None
        gcs = mavutil.mavlink_connection(
            self.sitl.url(2), source_system=255, source_component=190, dialect="ardupilotmega"
        )
        try:
            deadline = time.monotonic() + timeout_s
            if gcs.wait_heartbeat(timeout=timeout_s) is None:
                raise RuntimeError(f"no heartbeat on {self.sitl.url(2)}\n{self.logs()}")
            while time.monotonic() < deadline:
                gcs.mav.param_set_send(1, 1, b"SIM_SPEEDUP", float(speedup), 9)  # REAL32
                echo = gcs.recv_match(type="PARAM_VALUE", blocking=True, timeout=1.0)
                if (
                    echo is not None
                    and echo.param_id == "SIM_SPEEDUP"
                    and abs(echo.param_value - speedup) < 1e-3
                ):
                    self.say(f"SITL SIM_SPEEDUP {speedup:g}")
                    return
            raise RuntimeError(f"SITL did not take SIM_SPEEDUP {speedup:g}\n{self.logs()}")
        finally:
            gcs.close()

    def gcs_url(self) -> str:
        """A free SITL serial port for a ground station (SERIAL2)."""
        assert self.sitl is not None
        return self.sitl.url(2)

    def wait_event(
        self,
        name: str,
        timeout_s: float,
        cond: Callable[[dict], bool] | None = None,
        unless: Callable[[], bool] | None = None,
    ) -> dict | None:
        """The first ``COMPANION EVENT name`` (matching ``cond``) within ``timeout_s`` wall
        seconds, showing the companion's progress once per second; None as soon as
        ``unless()`` (asked once per second) is true."""
        assert self.companion is not None
        deadline = time.monotonic() + timeout_s
        last_say = 0.0
        while time.monotonic() < deadline:
            for _ev, fields in self.companion.events(name):
                if cond is None or cond(fields):
                    return fields
            for child in (self.companion, self.plant):
                if child is not None and child.proc.poll() is not None:
                    raise RuntimeError(
                        f"{child.name} exited ({child.proc.returncode}) while waiting for "
                        f"{name}\n{self.logs()}"
                    )
            if self.sitl is not None and self.sitl.proc.poll() is not None:
                raise RuntimeError(f"ArduCopter SITL exited\n{self.logs()}")
            if time.monotonic() - last_say >= 1.0:
                last_say = time.monotonic()
                line = _last_progress(self.companion.stderr_text())
                if line:
                    self.say(line)
                if unless is not None and unless():
                    return None
            time.sleep(0.05)
        raise TimeoutError(f"no companion event {name!r} within {timeout_s:.0f} s\n{self.logs()}")

    def wait_steering(self) -> float:
        """Wait for the first setpoint after the takeoff; its autopilot time [s]. A boot
        speed-up ends when the companion starts its takeoff (the flight runs at
        ``speedup``)."""
        o = self.options
        if o.boot_speedup > o.speedup:
            self.wait_event(
                "takeoff",
                o.startup_timeout_s,
                cond=lambda f: f.get("step") not in ("probe", "wait"),
            )
            self._set_sim_speedup(o.speedup)
        ev = self.wait_event("steering", o.startup_timeout_s)
        self.t0_s = float(ev.get("autopilot_time_s") or 0.0)
        self.say(f"companion steering at t={self.t0_s:.2f} s (autopilot time)")
        return self.t0_s

    def fly_to_goal(self) -> bool:
        """Wait (bounded by ``max_time_s`` of autopilot time) for the goal, or for the vehicle
        at rest in a hold the companion reported (:func:`settled_in_hold`); True if the
        companion reported the goal."""
        o = self.options
        assert self.companion is not None
        companion = self.companion

        def settled() -> bool:
            if settled_in_hold(self.out / "truth.csv", companion.events()):
                self.say("stopped in a reported hold")
                return True
            return False

        try:
            reached = self.wait_event(
                "goal_reached", o.max_time_s / o.speedup + 20.0, unless=settled
            )
        except TimeoutError:
            return False
        time.sleep(0.5)  # a little of the flight after the end, as the truth log samples it
        return reached is not None

    def logs(self) -> str:
        parts = [c.logs() for c in (self.companion, self.plant) if c is not None]
        if self.sitl is not None:
            parts.append(self.sitl.logs())
        return "\n".join(parts)

    def close(self) -> None:
        """Stop everything started (plant-sim, companion, SITL); keep their logs in out."""
        if self._closed:
            return
        self._closed = True
        for child in (self.plant, self.companion):
            if child is not None:
                child.stop()
        if self.sitl is not None:
            self.sitl.stop()
            with contextlib.suppress(OSError):
                (self.out / "arducopter_sitl.log").write_text(self.sitl.output())
        for child, name in ((self.companion, "companion.log"), (self.plant, "plant_sim.log")):
            if child is not None:
                with contextlib.suppress(OSError):
                    (self.out / name).write_text(child.stderr_text())
        for child in (self.plant, self.companion):
            if child is not None:
                child.close()
        if self.sitl is not None:
            self.sitl.close()

    def __enter__(self) -> SitlRig:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ---- judging -------------------------------------------------------------------
    def judge(self) -> SilResult:
        """Verdict and history from plant-sim's truth log (call after :meth:`close`)."""
        assert self.companion is not None
        events = self.companion.events()
        companion_stats = self.companion.stats("COMPANION STATS ")
        plant_stats = self.plant.stats("PLANT_SIM STATS ") if self.plant is not None else None
        truth_path = self.out / "truth.csv"
        truth = _read_truth(truth_path)
        if not truth or self.t0_s is None:
            raise RuntimeError(f"no flight to judge (truth rows: {len(truth)})\n{self.logs()}")
        intervals = _avoid_intervals(events)
        verdict = verdict_from_truth(
            truth,
            scene=self.options.scene_name,
            goal_ned_m=self.options.scene.goal_ned_m,
            t0_s=self.t0_s,
            avoid_intervals=intervals,
            frames=(companion_stats or {}).get("frames_processed", 0),
            wall_time_s=time.monotonic() - self._wall_start,
            hold_intervals=_hold_intervals(events),
        )
        return SilResult(
            verdict=verdict,
            history=history_from_truth(truth, self.t0_s, intervals),
            plant_stats=plant_stats,
            companion_stats=companion_stats,
            events=events,
            truth_path=truth_path,
        )


def speed_figures(truth: dict[str, np.ndarray], t0_s: float, t_end_s: float) -> dict:
    """Max and mean ground speed [m/s] between ``t0_s`` and ``t_end_s`` (autopilot time)."""
    t = truth["time_s"]
    sel = (t >= t0_s) & (t <= t_end_s)
    if not np.any(sel):
        return {"max_speed_mps": None, "mean_speed_mps": None}
    v = np.sqrt(sum(truth[k][sel] ** 2 for k in ("vel_n_mps", "vel_e_mps", "vel_d_mps")))
    return {
        "max_speed_mps": round(float(np.max(v)), 3),
        "mean_speed_mps": round(float(np.mean(v)), 3),
    }


@dataclass(frozen=True, eq=False)
class SitlResult:
    """A SITL run: the usual SIL result plus the speed figures."""

    sil: SilResult
    figures: dict = field(default_factory=dict)


def run_sitl_sil(options: SitlOptions, progress: Callable[[str], None] | None = None) -> SitlResult:
    """Fly the paper's scene on ArduCopter SITL; judge it from the truth log."""
    rig = SitlRig(options, progress)
    try:
        rig.start()
        t0 = rig.wait_steering()
        rig.fly_to_goal()
    finally:
        rig.close()
    result = rig.judge()
    v = result.verdict
    truth = _read_truth(result.truth_path)
    figures = {
        **speed_figures(truth, t0, t0 + v.sim_time_s),
        "time_to_goal_s": v.sim_time_s if v.reached_goal else None,
        "takeoff": next(
            (f for name, f in result.events if name == "takeoff" and f.get("step") == "done"),
            None,
        ),
        "plant_latency_ms": (result.plant_stats or {}).get("latency_ms"),
    }
    (Path(options.out_dir) / "sitl_figures.json").write_text(json.dumps(figures, indent=2) + "\n")
    return SitlResult(sil=result, figures=figures)
