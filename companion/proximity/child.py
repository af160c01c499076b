"""The OBSTACLE_DISTANCE process's own side: read the socket, forward, place, send.

Forked by :class:`~companion.proximity.process.ProximityProcess` (where the why and the
what are told). Each pass of :func:`run_child`'s loop, until the next send is due: wait
for the companion's UDP socket (while the main loop does not read it itself,
:meth:`~companion.proximity.shared.SharedMap.main_reads`), take every datagram waiting
into the pose reader (:mod:`companion.proximity.pose_reader`) and onto the queue to the
main loop (:mod:`companion.proximity.forward`), write what the stream takes, and stamp
the shared block with the time it ran; then, every period, the sectors of the newest map
from the freshest pose (its own, or the main loop's when that is newer), sent as
OBSTACLE_DISTANCE to the link's peers with the shared sequence number.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import math
import os
import select
import signal
import socket
import time
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.known_space import KnownSpaceConfig
from companion.link.messages import obstacle_distance_message
from companion.proximity.forward import PENDING_BYTES, ForwardQueue
from companion.proximity.pose_reader import PoseReader
from companion.proximity.sectors import ProximityConfig
from companion.proximity.sender import ProximitySender, pose_age_s, position_at_send
from companion.proximity.shared import SharedLink, SharedMap, SharedPose
from companion.proximity.stream import MapSnapshot
from protocols.signing import signing_timestamp_now

__all__ = ["SIGNING_LINK_ID", "ProcessSpec", "run_child"]

#: MAVLink 2 signing link id of the process's stream (the main loop signs as link 0).
SIGNING_LINK_ID = 1
_LATE_S = 0.25  # a send this long after the previous one is logged [s host]
_READS_PER_PASS = 2000  # datagrams the process reads before it looks at its timer again
_FLUSH_WAIT_S = 0.005  # datagrams wait in the process: look again this soon [s]
_PR_SET_PDEATHSIG = 1
_log = logging.getLogger("companion")


@dataclass(frozen=True)
class ProcessSpec:
    """What the process needs."""

    proximity: ProximityConfig
    space: KnownSpaceConfig
    link_fd: int  # the companion's UDP socket, inherited through the fork
    system_id: int
    component_id: int
    signing_secret: bytes | None
    parent_pid: int
    autopilot: tuple[int, int] = (1, 1)  # (system, component) whose pose the process reads


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


def run_child(spec: ProcessSpec, shared: SharedMap, ready_fd: int, forward: socket.socket) -> int:
    """The forked process: ends with the companion, leaves the companion's signal
    handlers (SIGTERM ends it; SIGINT is the companion's to handle), then sends."""
    _die_with_parent()
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if os.getppid() != spec.parent_pid:
        return 0
    return _run(spec, shared, ready_fd, forward)


class _Wire:
    """The process's writes on the companion's socket: OBSTACLE_DISTANCE, signed as link
    :data:`SIGNING_LINK_ID` with a timestamp never below the main loop's, to each peer."""

    def __init__(self, spec: ProcessSpec) -> None:
        # a duplicate of the inherited descriptor: closing it leaves the companion's alone;
        # its blocking mode (shared with the companion) is not touched
        self._sock = socket.socket(fileno=os.dup(spec.link_fd))
        self._mav = mavlink.MAVLink(None, srcSystem=spec.system_id, srcComponent=spec.component_id)
        self._signing = spec.signing_secret is not None
        if self._signing:
            sig = self._mav.signing
            sig.secret_key = spec.signing_secret
            sig.link_id = SIGNING_LINK_ID
            sig.sign_outgoing = True
            sig.timestamp = signing_timestamp_now()

    def send(self, msg, link: SharedLink, seq: int) -> tuple[int, int]:
        """(datagrams sent, failed) to ``link``'s peers, as sequence number ``seq``."""
        mav = self._mav
        if self._signing:
            mav.signing.timestamp = max(mav.signing.timestamp, link.signing_floor)
        mav.seq = seq
        buf = msg.pack(mav)
        sent = failed = 0
        for addr in link.peers:
            try:
                self._sock.sendto(buf, addr)
                sent += 1
            except OSError as exc:  # a full buffer (the socket is non-blocking), no route
                failed += 1
                _log.debug("OBSTACLE_DISTANCE process: send to %s failed: %s", addr, exc)
        return sent, failed

    def fileno(self) -> int:
        return self._sock.fileno()

    def read(self, poses: PoseReader, queue: ForwardQueue) -> None:
        """Every datagram waiting on the socket (never blocks: ``MSG_DONTWAIT``), into
        ``poses`` and, unchanged with its source, onto ``queue`` for the main loop."""
        for _ in range(_READS_PER_PASS):
            try:
                data, addr = self._sock.recvfrom(65535, socket.MSG_DONTWAIT)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:  # e.g. an ICMP error reported on the socket: go on
                _log.debug("OBSTACLE_DISTANCE process: receive: %s", exc)
                return
            poses.feed(data, time.monotonic_ns())
            queue.push(addr, data)

    def close(self) -> None:
        self._sock.close()


def _run(spec: ProcessSpec, shared: SharedMap, ready_fd: int, forward: socket.socket) -> int:
    wire = _Wire(spec)
    shared.set_counter("realtime", _realtime(spec.proximity.realtime_priority))
    sender = ProximitySender(spec.proximity)
    poses = PoseReader(spec.autopilot, spec.signing_secret)
    queue = ForwardQueue()
    forwarding = True  # False once the main loop's end of the stream is gone
    snapshot: MapSnapshot | None = None
    shared_pose: SharedPose | None = None
    link = SharedLink((), 0)
    seen_seq = -1
    period_s = sender.period_s
    next_s = time.monotonic()
    last_s = float("-inf")
    os.write(ready_fd, b"ready\n")
    os.close(ready_fd)
    while os.getppid() == spec.parent_pid:
        shared.set_alive_ns(time.monotonic_ns())
        reading = forwarding and not shared.main_reads()
        wait_s = max(next_s - time.monotonic(), 0.0)
        if len(queue):
            wait_s = min(wait_s, _FLUSH_WAIT_S)
        try:
            if reading:
                select.select([wire.fileno()], [], [], wait_s)
                wire.read(poses, queue)
            elif wait_s > 0.0:
                time.sleep(wait_s)
            if forwarding and len(queue):
                queue.flush(forward)
        except OSError as exc:  # closing our end tells the main loop to read the socket
            forwarding = False
            forward.close()
            _log.warning("OBSTACLE_DISTANCE process: forwarding stopped: %s", exc)
        _count_forwarding(shared, poses, queue)
        now_s = time.monotonic()
        if now_s < next_s:
            continue
        try:
            seq = shared.sequence()
            if seq != seen_seq:
                ok, snap = shared.read()
                if ok:
                    snapshot, seen_seq = snap, seq
            ok, newest = shared.read_pose()
            if ok:
                shared_pose = newest
            ok, newest_link = shared.read_link()
            if ok and newest_link is not None:
                link = newest_link
            own = poses.pose()
            pose = _pose_to_use(own, shared_pose, reading)
            if pose is not None and pose is own:
                shared.count("own_pose")
            _send(wire, link, sender, shared, pose, snapshot, now_s)
        except Exception:  # counted and logged: the stream must go on
            shared.count("errors")
            _log.exception("OBSTACLE_DISTANCE process: a send failed")
        gap_s = now_s - last_s
        if math.isfinite(gap_s):
            shared.set_counter("longest_us", max(shared.counter("longest_us"), int(gap_s * 1e6)))
            if gap_s > _LATE_S:
                shared.count("late")
                _log.warning(
                    "OBSTACLE_DISTANCE process late: %.3f s since its previous send", gap_s
                )
        last_s = now_s
        next_s = max(next_s + period_s, now_s + 0.5 * period_s)
    wire.close()  # the shared block is the companion's: it unlinks it
    return 0


def _pose_to_use(
    own: SharedPose | None, shared: SharedPose | None, reading: bool
) -> SharedPose | None:
    """While the process reads the socket, its own pose (every datagram reaches it first;
    the main loop's copy of the same message carries the later time the main loop read
    it, which would understate its age), else (none yet, or the main loop reads the
    socket itself) the one read last."""
    if reading and own is not None:
        return own
    if own is None or (shared is not None and shared.received_ns > own.received_ns):
        return shared
    return own


def _count_forwarding(shared: SharedMap, poses: PoseReader, queue: ForwardQueue) -> None:
    dropped_before = shared.counter("forward_dropped")
    shared.set_counter("forwarded", queue.forwarded)
    shared.set_counter("forward_dropped", queue.dropped)
    shared.set_counter("pose_refused", poses.refused)
    if queue.dropped > dropped_before:
        _log.warning(
            "OBSTACLE_DISTANCE process: %d datagrams not forwarded to the main loop (its "
            "queue of %d bytes is full)",
            queue.dropped,
            PENDING_BYTES,
        )


def _send(
    wire: _Wire,
    link: SharedLink,
    sender: ProximitySender,
    shared: SharedMap,
    pose: SharedPose | None,
    snapshot: MapSnapshot | None,
    now_s: float,
) -> None:
    rate, stamp_ns = shared.clock()
    pos = yaw = None
    if snapshot is None:
        shared.count("no_map")
    if pose is not None:
        age_s = pose_age_s(
            time.monotonic_ns(), pose.received_ns, pose.frame_ns, rate, pose.host_frame_clock
        )
        pos = position_at_send(pose.pos_ned_m, pose.vel_ned_mps, age_s)
        if pos is None:
            shared.count("stale_pose")
        else:
            yaw = pose.yaw_rad
            age_us = int(age_s * 1e6)
            if age_us > shared.counter("pose_age_max_us"):
                shared.set_counter("pose_age_max_us", age_us)
    if snapshot is not None and snapshot.capture_ns is not None:
        stamp_ns = snapshot.capture_ns
    sectors = sender.on_timer(snapshot, pos, yaw, now_s)
    message = obstacle_distance_message(max(stamp_ns, 0) // 1000, sectors)
    sent, failed = wire.send(message, link, shared.next_seq())
    if sent:
        shared.count("sent")
    elif not failed:
        shared.count("no_peer")  # udpin before any peer wrote to the companion
    if failed:
        shared.count("errors", failed)
