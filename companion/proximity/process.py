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

**One socket, one peer.** The process sends through the companion's own UDP socket,
inherited through the fork, to the peers the main loop sends to (``udpout``'s destination,
or every peer a ``udpin`` socket has heard from: :meth:`MavlinkConnection.udp_peers
<companion.link.connection.MavlinkConnection.udp_peers>`), so the autopilot, a router or a
serial-to-UDP bridge that answers only one peer sees one: the companion's port. Serial
ports and TCP streams are not shared (a frame written by one process could interleave
with the other's): the watchdog thread sends there.

**The socket's only reader.** Measured at stop 43: at load 18–24 the main loop stalled for
~2 s on two 8 m/s approaches; a pose that only the main loop read went stale, the process
sent every sector unknown, and ArduCopter, with no data, let the pilot fly on. So the
process reads the socket (two readers would take each other's datagrams: the main loop
does not): it places the vehicle with the LOCAL_POSITION_NED and ATTITUDE it decodes
itself as they arrive (:mod:`~companion.proximity.pose_reader`: only those two, found by
the message id in the header; with a key only correctly signed ones, with its own replay
state), and forwards every datagram, unchanged and in order, with its source address, to
the main loop (:mod:`~companion.proximity.forward`: a local stream socket created before
the fork, 2 MB of buffer and 8 MB of queue in the process, drops counted), which parses
them exactly as it parsed its own reads
(:meth:`~companion.link.connection.MavlinkConnection.forward_from`: signing, TIMESYNC,
peers unchanged) and keeps sending on the socket. Telemetry is never lost to a dead or
stopped helper: when the process has ended (``waitpid``, or its end of the stream closed)
or has not run its loop for :data:`FORWARD_STALL_S`, the main loop reads the socket
itself (:meth:`ProximityProcess.main_reads`, checked every pass; said in the log the
first time, counted as ``takeovers``), and hands it back when a stopped process runs
again. At the hand-over a datagram the process had read but not yet forwarded reaches
the main loop after the ones it reads itself (reordered, not lost), unless the process
was killed holding it (lost: at most what arrived in its last pass).

What the process has from the main loop (:class:`~companion.proximity.shared.SharedMap`,
one shared-memory block, a sequence lock per part: the main loop never waits; a copy read
during a write is discarded and the previous one kept):

* **the map**, a :class:`~companion.proximity.stream.MapSnapshot` slab written after each
  frame;
* **the pose** the core accepted from LOCAL_POSITION_NED and ATTITUDE (after its range,
  boot-time and ordering checks), with the host time its position was read, written
  whenever it changed: the fallback, used while the main loop reads the socket itself
  or before the process has a pose of its own. At each send the position (the process's
  own or this one) is carried forward by its velocity over its age
  (:func:`~companion.proximity.sender.pose_age_s`): the host time since it was read × the
  frame clock's rate, and with frames on the host clock at least the
  time since the autopilot stamped it (TIMESYNC-mapped: it counts the time the message
  waited for a busy main loop). A pose older than
  :data:`~companion.proximity.sender.POSE_STALE_S` (0.5 s) places nothing: every sector
  goes out unknown (``UINT16_MAX``), never clear, until telemetry arrives again; counted
  (``stale_pose``);
* **the link**: the peers and the main loop's signing timestamp;
* **the reader hand-over** and **one MAVLink sequence counter** for both senders
  (:meth:`~companion.proximity.shared.SharedMap.next_seq`);
* the frame clock's rate and newest stamp (the message's ``time_usec`` before a map).

**Signing.** MAVLink 2 keys the replay check by (system, component, link id): each stream's
timestamp must grow strictly, and a new stream's may lag the receiver's own timestamp
by at most one minute (``mavlink_signature_check`` in the C library ArduPilot and PX4
build, ``MAVLink.check_signature`` in pymavlink, :class:`protocols.signing.SignatureVerifier`
here). Two senders cannot share one counter without a lock across processes, so the
process signs as link id :data:`SIGNING_LINK_ID` (the main loop is link 0): two streams,
each strictly increasing. Its timestamp never falls below the main loop's (shared each
pass), which follows the newest authentic timestamp the autopilot sent: after an
autopilot reboot (its streams forgotten) the process's stream is within the minute as the
main loop's is. The sequence number is one counter in the shared block for both
senders (before issue 34's last step, two interleaved counters made a ground station
count every interleaving as loss); it is not atomic across processes and is taken just
before the send, so two sends in the same microseconds may carry one number twice or
reach the wire in the other order (measured: 689 of 693 steps consecutive over 6 s of
100 Hz main-loop sends beside the process).

It sends every period (:attr:`ProximityConfig.rate_hz`) the sectors of the newest map;
the main loop still sends each frame's sectors (its own stream, what a replay
reproduces). It dies with the companion: ``PR_SET_PDEATHSIG`` and a parent check every
period; its log lines go to the companion's stderr (the inherited logger) and its figures
(sends, errors, longest gap, real-time, datagrams forwarded and dropped, sends placed with
its own pose, the oldest pose a send used) to the companion's status and exit
statistics. Its loop is :mod:`companion.proximity.child`.
"""

from __future__ import annotations

import contextlib
import logging
import os
import select
import signal
import time
from dataclasses import replace

from companion.proximity.child import SIGNING_LINK_ID, ProcessSpec, run_child
from companion.proximity.forward import ForwardReader, forward_pair
from companion.proximity.sender import ProximitySender
from companion.proximity.shared import SharedLink, SharedMap, SharedPose
from companion.proximity.stream import MapSnapshot, VehiclePose, warm_up

__all__ = [
    "FORWARD_STALL_S",
    "SIGNING_LINK_ID",
    "ProcessSpec",
    "ProximityProcess",
    "own_process_refusal",
]

_READY_TIMEOUT_S = 30.0  # a forked process: seconds only on a starved machine
#: The process has not run its loop for this long [s host]: the main loop reads the socket
#: itself until it runs again (the core's telemetry failsafe would count a longer wait as
#: lost telemetry; three periods of sends).
FORWARD_STALL_S = 0.3
_log = logging.getLogger("companion")


def own_process_refusal(url: str) -> str | None:
    """Why the stream cannot have a process of its own on link ``url`` (None: it can).
    The process shares the companion's UDP socket (``udpout``, ``udpin``, ``udp``); a
    serial port or TCP stream would interleave two writers' bytes, and a broadcast link
    learns its peer only by reading."""
    if not hasattr(os, "fork"):
        return "this platform cannot fork"
    if not url.startswith(("udpout:", "udpin:", "udp:")):
        return f"the link {url.split(':', 1)[0]!r} is not a UDP socket two processes can share"
    return None


class ProximityProcess:
    """The companion's side of the process (module docstring); the same interface as
    :class:`~companion.proximity.stream.ProximityStream` for the service, plus
    :meth:`share`, which the main loop calls each pass.

    Parameters
    ----------
    sender : ProximitySender
        The core's sender (its configuration; the process keeps its own figures).
    spec : ProcessSpec
        ``parent_pid`` is filled in here.
    """

    def __init__(self, sender: ProximitySender, spec: ProcessSpec) -> None:
        self.sender = sender
        self._shared = SharedMap(spec.space)
        self._spec = replace(spec, parent_pid=os.getpid())
        self._pose: SharedPose | None = None  # as last shared
        self._pose_key: tuple | None = None
        self._proc: _Forked | None = None
        self._rfd, self._wfd = os.pipe()  # never readable: selected on with no reader
        self._reader: ForwardReader | None = None  # the datagrams the process forwards
        self._main_reads = False  # the main loop reads the socket itself (the process not)
        self._takeovers = 0  # times the main loop took the socket over
        self._local_seq = 0  # the sequence number once the shared block is closed
        self._exit_reported = False
        self._final: dict | None = None  # the figures as of close()
        self._ready = False
        self.errors = 0  # the process ended by itself

    def start(self, link: SharedLink) -> None:
        """Fork the process (it has every module and kernel the companion loaded, so it
        sends within a second even on a loaded machine, where a fresh interpreter took
        17.7 s to import them at load 21), sending to ``link``'s peers until the main loop
        shares newer ones. Call before any thread is started (Zenoh).
        Raises RuntimeError when it cannot be started."""
        warm_up()  # here: the main loop's sends need the kernel too, and the child has it
        self._shared.write_link(link)
        self._shared.set_main_reads(False)
        self._shared.set_alive_ns(time.monotonic_ns())
        ready_r, ready_w = os.pipe()
        ours, theirs = forward_pair()
        try:
            pid = os.fork()
        except OSError as exc:
            for fd in (ready_r, ready_w):
                os.close(fd)
            ours.close()
            theirs.close()
            raise RuntimeError(f"OBSTACLE_DISTANCE process did not start: {exc}") from None
        if pid == 0:  # the child: never returns into the companion's code
            code = 1
            try:
                os.close(ready_r)
                ours.close()
                code = run_child(self._spec, self._shared, ready_w, theirs)
            except BaseException:
                with contextlib.suppress(BaseException):
                    _log.exception("OBSTACLE_DISTANCE process failed")
            finally:
                os._exit(code)
        os.close(ready_w)
        theirs.close()
        self._reader = ForwardReader(ours)
        self._proc = _Forked(pid, ready_r)

    def wait_ready(self, timeout_s: float = _READY_TIMEOUT_S) -> bool:
        """Wait (at most ``timeout_s``) until the process runs its loop; False if not."""
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
                    "OBSTACLE_DISTANCE process sending through the companion's socket "
                    "(pid %d, real-time: %s)",
                    proc.pid,
                    "yes" if self._shared.counter("realtime") else "no",
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
        if self._reader is not None:
            self._reader.close()
            self._reader = None
        self._main_reads = True
        self._shared.close()
        for fd in (self._rfd, self._wfd):
            with contextlib.suppress(OSError):
                os.close(fd)

    def fileno(self) -> int:
        """What the main loop selects on: the forwarded datagrams while the process reads
        the socket (else a descriptor never readable)."""
        reader = self._reader
        return self._rfd if reader is None or reader.closed else reader.fileno()

    def take_inbox(self) -> list:
        return []  # what the process reads reaches the main loop through forwarded()

    # ---- the socket's reader (the link's forwarder: MavlinkConnection.forward_from) -----
    def forwarded(self) -> list[tuple[tuple[str, int], bytes]]:
        """The datagrams the process read since the last call, in order."""
        reader = self._reader
        return [] if reader is None else reader.take()

    def main_reads(self) -> bool:
        """Whether the main loop must read the socket itself: the process ended, its
        forwarding stream closed, or it has not run its loop for :data:`FORWARD_STALL_S`
        (until it runs again). Said in the log the first time; counted each time."""
        proc, reader = self._proc, self._reader
        if proc is None or reader is None or proc.poll() is not None:
            why = "ended"
        elif reader.closed:
            why = "stopped forwarding"
        elif time.monotonic_ns() - self._shared.alive_ns() > FORWARD_STALL_S * 1e9:
            why = f"has not run for {FORWARD_STALL_S} s"
        else:
            why = None
        if (why is not None) != self._main_reads:
            self._main_reads = why is not None
            if self._shared.header is not None:
                self._shared.set_main_reads(self._main_reads)
            if self._main_reads:
                self._takeovers += 1
                log = _log.warning if self._takeovers == 1 else _log.debug
                log(
                    "the OBSTACLE_DISTANCE process %s (it read the companion's socket): the "
                    "main loop reads it itself%s",
                    why,
                    " until the process runs again" if why.startswith("has not") else "",
                )
        return self._main_reads

    def next_seq(self) -> int:
        """The companion's next MAVLink sequence number, shared with the process."""
        if self._shared.header is None:  # closed
            self._local_seq = (self._local_seq + 1) % 256
            return self._local_seq
        return self._shared.next_seq()

    def observe(self, messages, now_ns: int) -> None:
        """Nothing: the pose comes from the core, through :meth:`share`."""

    def pose(self) -> VehiclePose | None:
        """The pose as last shared (None: none yet)."""
        p = self._pose
        if p is None:
            return None
        return VehiclePose(p.pos_ned_m, p.vel_ned_mps, p.received_ns, p.yaw_rad)

    def share(self, pose: SharedPose | None, link: SharedLink) -> None:
        """The core's newest pose (written when it changed) and the link's peers and
        signing timestamp (when they changed); each main-loop pass."""
        key = None if pose is None else (pose.frame_ns, pose.received_ns)
        if key != self._pose_key:
            self._pose_key, self._pose = key, pose
            self._shared.write_pose(pose)
        self._shared.write_link(link)

    def set_map(self, snapshot: MapSnapshot | None) -> None:
        self._shared.write(snapshot)

    def set_clock(self, rate: float, stamp_ns: int | None) -> None:
        self._shared.write_clock(rate, None if stamp_ns is None else max(int(stamp_ns), 0))

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
        """Sends, errors, late sends, stale poses, sends with no peer to send to and the
        longest gap [s host] of the process; ``main_longest_gap_s``: the main loop's own."""
        if self._final is not None:
            return self._final
        sh = self._shared
        alive = self._proc is not None and self._proc.poll() is None
        return {
            "process": True,
            "alive": alive,
            "ready": self._ready,
            "sent": sh.counter("sent"),
            "errors": sh.counter("errors") + self.errors,
            "late": sh.counter("late"),
            "stale_pose": sh.counter("stale_pose"),
            "no_map": sh.counter("no_map"),
            "no_peer": sh.counter("no_peer"),
            "realtime": bool(sh.counter("realtime")),
            "longest_gap_s": round(sh.counter("longest_us") * 1e-6, 3),
            "main_longest_gap_s": round(self.sender.longest_gap_s, 3),
            "map_overflows": sh.overflows,
            "forwarded": sh.counter("forwarded"),
            "forward_dropped": sh.counter("forward_dropped"),
            "own_pose": sh.counter("own_pose"),
            "pose_refused": sh.counter("pose_refused"),
            "pose_age_max_s": round(sh.counter("pose_age_max_us") * 1e-6, 3),
            "main_reads": self._main_reads,
            "takeovers": self._takeovers,
        }


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


def new_spec(config, sender: ProximitySender, link_fd: int) -> ProcessSpec:
    """The spec of a companion configuration (:class:`~companion.config.CompanionConfig`)
    whose link's socket is ``link_fd``."""
    link = config.link
    return ProcessSpec(
        proximity=sender.config,
        space=config.known_space,
        link_fd=link_fd,
        system_id=link.system_id,
        component_id=link.component_id,
        signing_secret=None if link.signing_key is None else link.signing_key.secret,
        parent_pid=0,
        autopilot=(link.target_system, link.target_component),
    )
