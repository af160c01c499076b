"""OBSTACLE_DISTANCE from a process of its own: the stream does not stall with the companion.

Why a process (issue 34, measured with ``benchmarks/bench_proximity.py``): the watchdog
thread (:mod:`companion.proximity.stream`) shares the companion's interpreter lock with the
main loop, whose numba kernels (planner, map update, perception) and Python run for tens
of milliseconds of CPU at a time without releasing it. On a loaded 2-core machine each of
those milliseconds becomes ten of wall time (the process gets a tenth of a core), and the
thread, which needs the lock to send, waited up to 1.04 s: longer than the autopilots'
0.5 s proximity timeout (py-spy on an 8 m/s approach: pymavlink's pure-Python parser,
``KnownSpace.integrate``, the map's recentring and guidance's track memory hold it). A
process has its own interpreter, so nothing the main loop runs delays it; as a normal task
it still waited up to 1.7 s for a processor at load 20, so it asks for ``SCHED_FIFO``
(:attr:`ProximityConfig.realtime_priority`; ~1 ms of CPU per send) and then runs when its
timer expires. It is forked from the companion when the link opens (a fresh interpreter
took 17.7 s to import at load 21), after the sector kernel is loaded.

What the process has of its own, and what it shares:

* **its own MAVLink socket** to the autopilot, with the companion's system and component
  ids (``udpout`` links: the autopilot or a MAVLink router answers every peer that writes to
  it, as ArduPilot's UDP ports, mavlink-router and plant-sim do); with a signing key it
  signs as link id :data:`SIGNING_LINK_ID` so that its timestamps and the main loop's are
  two streams (MAVLink 2 signing keys the replay check by system, component and link id).
  It reads the autopilot's LOCAL_POSITION_NED and ATTITUDE there itself, so the vehicle's
  position keeps arriving while the companion is busy;
* **the map**, as a :class:`~companion.proximity.stream.MapSnapshot` that the main loop
  writes after each frame into shared memory (:class:`SharedMap`, a sequence lock: the
  writer never waits; a reader that saw a write in progress keeps its previous copy);
* the frame clock's rate and newest stamp (for the message's ``time_usec`` before a map).

It sends every period (:attr:`ProximityConfig.rate_hz`) the sectors of the newest map at
the vehicle's position carried forward to the send
(:func:`~companion.proximity.sender.position_at_send`); the main loop still sends each
frame's sectors (its own stream, what a replay reproduces). It dies with the companion:
``PR_SET_PDEATHSIG`` and a parent check every period; its log lines go to the companion's
stderr (the inherited logger) and its figures (sends, errors, longest gap, real-time) to
the companion's status and exit statistics.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import math
import os
import select
import signal
import time
from dataclasses import dataclass, replace
from multiprocessing import shared_memory

import numpy as np

from companion.known_space import KnownSpaceConfig
from companion.link.connection import MavlinkConnection
from companion.link.messages import obstacle_distance_message
from companion.proximity.sectors import ProximityConfig
from companion.proximity.sender import ProximitySender, position_at_send
from companion.proximity.stream import MapSnapshot, TelemetryPose, warm_up
from protocols.signing import SigningKey

__all__ = [
    "SIGNING_LINK_ID",
    "ProcessSpec",
    "ProximityProcess",
    "SharedMap",
    "own_process_possible",
]

#: MAVLink 2 signing link id of the process's stream (the main loop signs as link 0).
SIGNING_LINK_ID = 1
_READY_TIMEOUT_S = 30.0  # a forked process opens a socket: seconds only on a starved machine
_LATE_S = 0.25  # a send this long after the previous one is logged [s host]
_PR_SET_PDEATHSIG = 1
_log = logging.getLogger("companion")

# header words (int64) of the shared map
_SEQ, _PRESENT, _CAPTURE, _STAMP = 0, 1, 2, 3
_LAYER0 = 4  # per layer: present, nx, ny, nz, ox, oy, oz, frames
_LAYER_WORDS = 8
_HEADER_WORDS = _LAYER0 + 2 * _LAYER_WORDS
# float64 words: range_m of each layer, frame-clock rate
_RANGE0, _RATE = 0, 2
_FLOAT_WORDS = 3
# counters (int64) the process writes
_SENT, _ERRORS, _LONGEST_US, _LATE_SENDS, _STALE, _TELEMETRY, _NO_MAP, _REALTIME = range(8)
_COUNTER_WORDS = 8
_NO_CAPTURE = -1


def own_process_possible(url: str) -> bool:
    """A second socket reaches the autopilot only on ``udpout`` links (it answers every
    peer); a serial port, a bound ``udpin`` port or ArduPilot's one-client TCP do not."""
    return url.startswith("udpout:")


@dataclass(frozen=True)
class ProcessSpec:
    """What the process needs."""

    proximity: ProximityConfig
    space: KnownSpaceConfig
    url: str
    system_id: int
    component_id: int
    baud: int
    signing_secret: bytes | None
    autopilot: tuple[int, int]
    parent_pid: int


class SharedMap:
    """The map slab, the frame clock and the process's counters in one shared memory block.

    Parameters
    ----------
    space : KnownSpaceConfig
        The companion's map (it sizes the block: every layer's whole grid fits).
    name : str or None
        Attach to this block (the process); None creates one (the companion).
    """

    def __init__(self, space: KnownSpaceConfig, name: str | None = None) -> None:
        layers = [space] + ([] if space.far_config() is None else [space.far_config()])
        self._capacity = [c.size_xy_vox * c.size_xy_vox * c.size_z_vox for c in layers]
        self._configs = layers
        size = 8 * (_HEADER_WORDS + _FLOAT_WORDS + _COUNTER_WORDS) + 2 * max(self._capacity)
        if name is None:
            self.shm = shared_memory.SharedMemory(create=True, size=size)
        else:
            self.shm = shared_memory.SharedMemory(name=name)
        self._owner = name is None
        buf = self.shm.buf
        off = 0
        self.header = np.ndarray((_HEADER_WORDS,), np.int64, buf, off)
        off += 8 * _HEADER_WORDS
        self.floats = np.ndarray((_FLOAT_WORDS,), np.float64, buf, off)
        off += 8 * _FLOAT_WORDS
        self.counters = np.ndarray((_COUNTER_WORDS,), np.int64, buf, off)
        off += 8 * _COUNTER_WORDS
        self._grids = []
        for cap in self._capacity:
            self._grids.append(np.ndarray((cap,), np.int8, buf, off))
            off += max(self._capacity)
        if self._owner:
            self.header[:] = 0
            self.header[_CAPTURE] = _NO_CAPTURE
            self.floats[:] = 0.0
            self.floats[_RATE] = 1.0
            self.counters[:] = 0
        self.overflows = 0  # snapshots larger than the block (not expected: counted)

    @property
    def name(self) -> str:
        return self.shm.name

    def close(self) -> None:
        # the views must go before the buffer can be released
        self.header = self.floats = self.counters = None
        self._grids = []
        with contextlib.suppress(BufferError, OSError):
            self.shm.close()
        if self._owner:
            with contextlib.suppress(FileNotFoundError):
                self.shm.unlink()

    # ---- writer (the companion's main loop) --------------------------------------------
    def write(self, snapshot: MapSnapshot | None) -> None:
        """Publish ``snapshot`` (None: no map); never waits for the reader."""
        h = self.header
        layers = [] if snapshot is None else [snapshot] + ([snapshot.far] if snapshot.far else [])
        if any(s.grid.size > cap for s, cap in zip(layers, self._capacity, strict=False)):
            self.overflows += 1
            layers = []
        h[_SEQ] += 1  # odd: a write in progress
        h[_PRESENT] = 1 if layers else 0
        h[_CAPTURE] = _NO_CAPTURE
        if layers and layers[0].capture_ns is not None:
            h[_CAPTURE] = layers[0].capture_ns
        for i in range(len(self._capacity)):
            base = _LAYER0 + i * _LAYER_WORDS
            if i >= len(layers):
                h[base] = 0
                continue
            s = layers[i]
            n = s.grid.size
            self._grids[i][:n] = s.grid.reshape(-1)
            h[base : base + 8] = (1, *s.grid.shape, *(int(v) for v in s.origin_vox), s.frames)
            self.floats[_RANGE0 + i] = s.range_m
        h[_SEQ] += 1  # even: complete

    def write_clock(self, rate: float, stamp_ns: int) -> None:
        """The frame clock's rate and newest stamp (single words: no lock needed)."""
        self.floats[_RATE] = rate
        self.header[_STAMP] = stamp_ns

    # ---- reader (the process) ----------------------------------------------------------
    def sequence(self) -> int:
        return int(self.header[_SEQ])

    def read(self) -> tuple[bool, MapSnapshot | None]:
        """(consistent, snapshot): a copy of the newest map, or (False, None) when a write
        was in progress or happened during the copy (keep the previous one)."""
        h = self.header
        seq = int(h[_SEQ])
        if seq % 2:
            return False, None
        snap: MapSnapshot | None = None
        if h[_PRESENT]:
            capture = int(h[_CAPTURE])
            built = []
            for i, config in enumerate(self._configs):
                base = _LAYER0 + i * _LAYER_WORDS
                present, nx, ny, nz, ox, oy, oz, frames = (int(v) for v in h[base : base + 8])
                if not present:
                    break
                n = nx * ny * nz
                if n > self._capacity[i] or min(nx, ny, nz) < 0:
                    return False, None
                built.append(
                    MapSnapshot(
                        grid=self._grids[i][:n].copy().reshape(nx, ny, nz),
                        origin_vox=np.array((ox, oy, oz), dtype=np.int64),
                        config=config,
                        range_m=float(self.floats[_RANGE0 + i]),
                        frames=frames,
                        far=None,
                        capture_ns=None if capture == _NO_CAPTURE else capture,
                    )
                )
            if built:
                snap = built[0] if len(built) == 1 else replace(built[0], far=built[1])
        if int(h[_SEQ]) != seq:
            return False, None
        return True, snap

    def clock(self) -> tuple[float, int]:
        rate = float(self.floats[_RATE])
        return (rate if math.isfinite(rate) and rate > 0.0 else 1.0), int(self.header[_STAMP])


class ProximityProcess:
    """The companion's side of the process (module docstring); the same interface as
    :class:`~companion.proximity.stream.ProximityStream` for the service.

    Parameters
    ----------
    sender : ProximitySender
        The core's sender (its configuration; the process keeps its own figures).
    spec : ProcessSpec
        Without ``shm_name`` and ``parent_pid`` (filled in here).
    """

    def __init__(self, sender: ProximitySender, spec: ProcessSpec) -> None:
        self.sender = sender
        self._shared = SharedMap(spec.space)
        self._spec = replace(spec, parent_pid=os.getpid())
        self._pose = TelemetryPose(spec.autopilot)
        self._proc: _Forked | None = None
        self._rfd, self._wfd = os.pipe()  # never readable: the service selects on it too
        self._exit_reported = False
        self._final: dict | None = None  # the figures as of close()
        self._ready = False
        self.errors = 0  # the process ended by itself

    def start(self) -> None:
        """Fork the process (it has every module and kernel the companion loaded, so it
        sends within a second even on a loaded machine, where a fresh interpreter took
        17.7 s to import them at load 21). Call before any thread is started (Zenoh).
        Raises RuntimeError when it cannot be started."""
        warm_up()  # here: the main loop's sends need the kernel too, and the child has it
        ready_r, ready_w = os.pipe()
        try:
            pid = os.fork()
        except OSError as exc:
            os.close(ready_r)
            os.close(ready_w)
            raise RuntimeError(f"OBSTACLE_DISTANCE process did not start: {exc}") from None
        if pid == 0:  # the child: never returns into the companion's code
            code = 1
            try:
                os.close(ready_r)
                code = _child(self._spec, self._shared, ready_w)
            except BaseException:
                with contextlib.suppress(BaseException):
                    _log.exception("OBSTACLE_DISTANCE process failed")
            finally:
                os._exit(code)
        os.close(ready_w)
        self._proc = _Forked(pid, ready_r)

    def wait_ready(self, timeout_s: float = _READY_TIMEOUT_S) -> bool:
        """Wait (at most ``timeout_s``) until the process sends; False if it did not."""
        deadline = time.monotonic() + timeout_s
        while not self._poll_ready() and self._proc is not None and self._proc.poll() is None:
            left = deadline - time.monotonic()
            if left <= 0.0:
                return False
            select.select([self._proc.stdout], [], [], min(left, 0.1))
        return self._ready

    def _poll_ready(self) -> bool:
        proc = self._proc
        if self._ready or proc is None or proc.stdout is None:
            return self._ready
        if select.select([proc.stdout], [], [], 0.0)[0]:
            self._ready = proc.stdout.readline().strip() == b"ready"
            if self._ready:
                _log.info(
                    "OBSTACLE_DISTANCE process sending (pid %d, real-time: %s)",
                    proc.pid,
                    "yes" if self._shared.counters[_REALTIME] else "no",
                )
        return self._ready

    def close(self) -> None:
        self._final = self.figures()  # the companion's exit statistics are taken after
        proc = self._proc
        if proc is not None:
            if proc.poll() is None:
                proc.terminate()
                if not proc.wait(timeout_s=2.0):
                    proc.kill()
                    proc.wait(timeout_s=2.0)
            if proc.stdout is not None:
                proc.stdout.close()
            self._proc = None
        self._shared.close()
        for fd in (self._rfd, self._wfd):
            with contextlib.suppress(OSError):
                os.close(fd)

    def fileno(self) -> int:
        return self._rfd

    def take_inbox(self) -> list:
        return []  # the process reads its own socket; the main loop reads the companion's

    def observe(self, messages, now_ns: int) -> None:
        for msg in messages:
            self._pose.observe(msg, now_ns)

    def pose(self):
        return self._pose.pose()

    def set_map(self, snapshot: MapSnapshot | None) -> None:
        self._shared.write(snapshot)

    def set_clock(self, rate: float, stamp_ns: int | None) -> None:
        if stamp_ns is not None:
            self._shared.write_clock(rate, max(int(stamp_ns), 0))
        else:
            self._shared.floats[_RATE] = rate

    def check(self) -> str | None:
        """Once, when the process has ended by itself: why (for the log and the status);
        logs once when it starts sending."""
        proc = self._proc
        if proc is None or self._exit_reported:
            return None
        self._poll_ready()
        code = proc.poll()
        if code is None:
            return None
        self._exit_reported = True
        self.errors += 1
        return f"the OBSTACLE_DISTANCE process ended (exit code {code}); the main loop sends alone"

    def figures(self) -> dict:
        """Sends, errors, late sends, stale poses and the longest gap [s host] of the
        process; ``main_longest_gap_s``: the main loop's own."""
        if self._final is not None:
            return self._final
        c = self._shared.counters
        alive = self._proc is not None and self._proc.poll() is None
        return {
            "process": True,
            "alive": alive,
            "ready": self._ready,
            "sent": int(c[_SENT]),
            "errors": int(c[_ERRORS]) + self.errors,
            "late": int(c[_LATE_SENDS]),
            "stale_pose": int(c[_STALE]),
            "no_map": int(c[_NO_MAP]),
            "telemetry": int(c[_TELEMETRY]),
            "realtime": bool(c[_REALTIME]),
            "longest_gap_s": round(int(c[_LONGEST_US]) * 1e-6, 3),
            "main_longest_gap_s": round(self.sender.longest_gap_s, 3),
            "map_overflows": self._shared.overflows,
        }


# ---- the process --------------------------------------------------------------------------
def _die_with_parent() -> None:
    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)


def _realtime(priority: int) -> bool:
    """``SCHED_FIFO`` at ``priority`` (0: none); False (said once) when not permitted."""
    if priority <= 0:
        return False
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, AttributeError) as exc:
        _log.info(
            "OBSTACLE_DISTANCE process: no real-time priority (%s): it runs as a normal task "
            "and may wait for a processor on a loaded machine",
            exc,
        )
        return False
    return True


class _Forked:
    """The forked process: its pid, exit status and the read end of its readiness pipe."""

    def __init__(self, pid: int, ready_fd: int) -> None:
        self.pid = pid
        self.stdout = os.fdopen(ready_fd, "rb", buffering=0)
        self.returncode: int | None = None

    def poll(self) -> int | None:
        if self.returncode is None:
            with contextlib.suppress(ChildProcessError):
                pid, status = os.waitpid(self.pid, os.WNOHANG)
                if pid:
                    self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def terminate(self) -> None:
        with contextlib.suppress(ProcessLookupError):
            os.kill(self.pid, signal.SIGTERM)

    def kill(self) -> None:
        with contextlib.suppress(ProcessLookupError):
            os.kill(self.pid, signal.SIGKILL)

    def wait(self, timeout_s: float) -> bool:
        """True once it has ended (bounded by ``timeout_s``)."""
        deadline = time.monotonic() + timeout_s
        while self.poll() is None:
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.01)
        return True


def _child(spec: ProcessSpec, shared: SharedMap, ready_fd: int) -> int:
    """The forked process: ends with the companion, leaves the companion's signal
    handlers (SIGTERM ends it; SIGINT is the companion's to handle), then sends."""
    _die_with_parent()
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if os.getppid() != spec.parent_pid:
        return 0
    return _run(spec, shared, ready_fd)


def _run(spec: ProcessSpec, shared: SharedMap, ready_fd: int) -> int:
    key = None if spec.signing_secret is None else SigningKey(spec.signing_secret)
    link = MavlinkConnection(
        spec.url,
        system_id=spec.system_id,
        component_id=spec.component_id,
        baud=spec.baud,
        signing_key=key,
        signing_link_id=SIGNING_LINK_ID,
    )
    link.open()
    shared.counters[_REALTIME] = _realtime(spec.proximity.realtime_priority)
    sender = ProximitySender(spec.proximity)
    pose = TelemetryPose(spec.autopilot)
    c = shared.counters
    snapshot: MapSnapshot | None = None
    seen_seq = -1
    period_s = sender.period_s
    fd = link.fileno()
    next_s = time.monotonic()
    last_s = float("-inf")
    _send(link, sender, shared, pose, snapshot, next_s)  # a peer of the autopilot at once
    os.write(ready_fd, b"ready\n")
    os.close(ready_fd)
    while os.getppid() == spec.parent_pid:
        now_s = time.monotonic()
        if now_s < next_s:
            if fd is not None:
                select.select([fd], [], [], next_s - now_s)
            else:
                time.sleep(min(next_s - now_s, 0.005))
        messages = link.poll()
        now_ns = time.monotonic_ns()
        for msg in messages:
            if pose.observe(msg, now_ns):
                c[_TELEMETRY] += 1
        now_s = time.monotonic()
        if now_s < next_s:
            continue
        try:
            if shared.sequence() != seen_seq:
                seq = shared.sequence()
                ok, snap = shared.read()
                if ok:
                    snapshot, seen_seq = snap, seq
            _send(link, sender, shared, pose, snapshot, now_s)
        except Exception:  # counted and logged: the stream must go on
            c[_ERRORS] += 1
            _log.exception("OBSTACLE_DISTANCE process: a send failed")
        gap_s = now_s - last_s
        if math.isfinite(gap_s):
            c[_LONGEST_US] = max(int(c[_LONGEST_US]), int(gap_s * 1e6))
            if gap_s > _LATE_S:
                c[_LATE_SENDS] += 1
                _log.warning(
                    "OBSTACLE_DISTANCE process late: %.3f s since its previous send", gap_s
                )
        last_s = now_s
        c[_SENT] += 1
        next_s = max(next_s + period_s, now_s + 0.5 * period_s)
    link.close()  # the shared block is the companion's: it unlinks it
    return 0


def _send(link, sender, shared: SharedMap, pose: TelemetryPose, snapshot, now_s: float) -> None:
    rate, stamp_ns = shared.clock()
    p = pose.pose()
    pos = yaw = None
    if snapshot is None:
        shared.counters[_NO_MAP] += 1
    if p is not None and p.yaw_rad is not None:
        age_s = (time.monotonic_ns() - p.received_ns) * 1e-9 * rate
        pos = position_at_send(p.pos_ned_m, p.vel_ned_mps, age_s)
        if pos is None:
            shared.counters[_STALE] += 1
        else:
            yaw = p.yaw_rad
    if snapshot is not None and snapshot.capture_ns is not None:
        stamp_ns = snapshot.capture_ns
    sectors = sender.on_timer(snapshot, pos, yaw, now_s)
    link.send(obstacle_distance_message(max(stamp_ns, 0) // 1000, sectors))


def new_spec(config, sender: ProximitySender) -> ProcessSpec:
    """The spec of a companion configuration (:class:`~companion.config.CompanionConfig`)."""
    link = config.link
    return ProcessSpec(
        proximity=sender.config,
        space=config.known_space,
        url=link.url,
        system_id=link.system_id,
        component_id=link.component_id,
        baud=link.baud,
        signing_secret=None if link.signing_key is None else link.signing_key.secret,
        autopilot=(link.target_system, link.target_component),
        parent_pid=0,
    )
