"""The OBSTACLE_DISTANCE process's shared memory: what the companion's main loop writes.

One block (:class:`SharedMap`) that the companion creates before it forks the process
(:mod:`companion.proximity.process`) and both map. The main loop is the only writer of
each part, the process the only reader (its counters the other way round); every part
is guarded by its own sequence word (a seqlock: odd while a write is in progress, so
the writer never waits and a reader that saw a write start or finish during its copy
discards the copy and keeps its previous one). Parts:

* **the map**: a :class:`~companion.proximity.stream.MapSnapshot` slab of each layer,
  written after each frame;
* **the pose**: the newest pose the core accepted from LOCAL_POSITION_NED and ATTITUDE
  (position, velocity, yaw), its time on the frame clock and the host time its position
  arrived (:class:`SharedPose`), written whenever the core's pose changed: the process's
  fallback when the main loop reads the MAVLink socket itself (the process reads it
  otherwise and decodes its own pose, :mod:`companion.proximity.pose_reader`);
* **the link**: the peers the companion's UDP socket sends to (up to :data:`MAX_PEERS`)
  and the main loop's signing timestamp (:attr:`SharedLink.signing_floor`);
* single words: the frame clock's rate and newest stamp;
* the process's counters (sends, errors, the longest gap, datagrams forwarded, ...);
* the reader hand-over (:meth:`SharedMap.set_main_reads`, :meth:`SharedMap.alive_ns`):
  which side reads the UDP socket, written by the main loop, and the host time the
  process last ran its loop, written by the process;
* the companion's MAVLink sequence number (:meth:`SharedMap.next_seq`), one counter for
  both senders of component 196.
"""

from __future__ import annotations

import contextlib
import math
import socket
import struct
from dataclasses import dataclass, replace
from multiprocessing import shared_memory

import numpy as np

from companion.known_space import KnownSpaceConfig
from companion.proximity.stream import MapSnapshot

__all__ = ["COUNTERS", "MAX_PEERS", "SharedLink", "SharedMap", "SharedPose"]

#: Peers of a ``udpin`` socket the process sends to (a ground station and an autopilot).
MAX_PEERS = 8

# header words (int64) of the map
_SEQ, _PRESENT, _CAPTURE, _STAMP = 0, 1, 2, 3
_LAYER0 = 4  # per layer: present, nx, ny, nz, ox, oy, oz, frames
_LAYER_WORDS = 8
_HEADER_WORDS = _LAYER0 + 2 * _LAYER_WORDS
# float64 words: range_m of each layer, frame-clock rate
_RANGE0, _RATE = 0, 2
_FLOAT_WORDS = 3
# the pose (int64): sequence, present, frame-clock time, host receipt time, host frames
_P_SEQ, _P_PRESENT, _P_FRAME_NS, _P_HOST_NS, _P_HOST_CLOCK = range(5)
_POSE_INT_WORDS = 5
_POSE_FLOAT_WORDS = 7  # pos (3), vel (3), yaw
# the link (int64): sequence, signing floor, number of peers, then (IPv4, port) per peer
_L_SEQ, _L_FLOOR, _L_N = range(3)
_LINK_WORDS = 3 + 2 * MAX_PEERS
#: Counters (int64) the process writes, by name.
COUNTERS = (
    "sent",
    "errors",
    "longest_us",
    "late",
    "stale_pose",
    "no_peer",
    "no_map",
    "realtime",
    "forwarded",  # datagrams handed to the main loop
    "forward_dropped",  # datagrams not handed over (the queue full): counted, logged
    "own_pose",  # sends placed with the pose the process decoded itself
    "pose_refused",  # LOCAL_POSITION_NED / ATTITUDE not used (signature, range, order)
    "pose_age_max_us",  # the oldest pose a send placed the vehicle with [µs, frame clock]
)
_COUNTER_WORDS = len(COUNTERS)
# the reader hand-over and the sequence number (int64)
_C_MAIN_READS, _C_ALIVE_NS, _C_SEQ = range(3)
_CONTROL_WORDS = 3
_NO_CAPTURE = -1
_READ_TRIES = 3  # a seqlock read retries this often before keeping the previous copy


@dataclass(frozen=True)
class SharedPose:
    """The core's newest pose, as the main loop shares it.

    ``frame_ns`` is on the frame clock; ``received_ns`` is the host monotonic time its
    position arrived; ``host_frame_clock``: frames (and so ``frame_ns``) are stamped on the
    host clock (a real camera, :class:`~companion.clock_model.FrameClock.HOST`).
    """

    pos_ned_m: tuple[float, float, float]
    vel_ned_mps: tuple[float, float, float]
    yaw_rad: float
    frame_ns: int
    received_ns: int
    host_frame_clock: bool


@dataclass(frozen=True)
class SharedLink:
    """Where the companion's socket sends, and the main loop's signing timestamp
    [10 µs since 2015] (the process signs no lower: see :mod:`companion.proximity.process`)."""

    peers: tuple[tuple[str, int], ...]
    signing_floor: int


class SharedMap:
    """The shared block (module docstring).

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
        words = (
            _HEADER_WORDS
            + _FLOAT_WORDS
            + _POSE_INT_WORDS
            + _POSE_FLOAT_WORDS
            + _LINK_WORDS
            + _COUNTER_WORDS
            + _CONTROL_WORDS
        )
        size = 8 * words + len(layers) * max(self._capacity)
        if name is None:
            self.shm = shared_memory.SharedMemory(create=True, size=size)
        else:
            self.shm = shared_memory.SharedMemory(name=name)
        self._owner = name is None
        off = 0

        def view(n: int, dtype) -> np.ndarray:
            nonlocal off
            out = np.ndarray((n,), dtype, self.shm.buf, off)
            off += out.nbytes
            return out

        self.header = view(_HEADER_WORDS, np.int64)
        self.floats = view(_FLOAT_WORDS, np.float64)
        self._pose_i = view(_POSE_INT_WORDS, np.int64)
        self._pose_f = view(_POSE_FLOAT_WORDS, np.float64)
        self._link = view(_LINK_WORDS, np.int64)
        self.counters = view(_COUNTER_WORDS, np.int64)
        self._control = view(_CONTROL_WORDS, np.int64)
        self._grids = []
        for _ in self._capacity:
            self._grids.append(view(max(self._capacity), np.int8))
        if self._owner:
            for part in (self.header, self._pose_i, self._link, self.counters, self._control):
                part[:] = 0
            self.header[_CAPTURE] = _NO_CAPTURE
            self.floats[:] = 0.0
            self.floats[_RATE] = 1.0
            self._pose_f[:] = 0.0
        self.overflows = 0  # snapshots larger than the block (not expected: counted)
        self._shared_link: SharedLink | None = None  # the writer's last, to skip repeats

    @property
    def name(self) -> str:
        return self.shm.name

    def counter(self, name: str) -> int:
        return int(self.counters[COUNTERS.index(name)])

    def count(self, name: str, by: int = 1) -> None:
        self.counters[COUNTERS.index(name)] += by

    def set_counter(self, name: str, value: int) -> None:
        self.counters[COUNTERS.index(name)] = value

    def close(self) -> None:
        # the views must go before the buffer can be released
        self.header = self.floats = self.counters = self._pose_i = self._pose_f = None
        self._link = self._control = None
        self._grids = []
        with contextlib.suppress(BufferError, OSError):
            self.shm.close()
        if self._owner:
            with contextlib.suppress(FileNotFoundError):
                self.shm.unlink()

    # ---- the map: written by the main loop after each frame ------------------------------
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

    def write_clock(self, rate: float, stamp_ns: int | None) -> None:
        """The frame clock's rate and newest stamp (None: unchanged; single words: no lock
        needed)."""
        self.floats[_RATE] = rate
        if stamp_ns is not None:
            self.header[_STAMP] = stamp_ns

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

    # ---- the pose: written by the main loop when the core's pose changed -----------------
    def write_pose(self, pose: SharedPose | None) -> None:
        """Publish the core's newest pose (None: none, e.g. after an autopilot restart)."""
        i, f = self._pose_i, self._pose_f
        i[_P_SEQ] += 1
        if pose is None:
            i[_P_PRESENT] = 0
        else:
            i[_P_PRESENT] = 1
            i[_P_FRAME_NS] = pose.frame_ns
            i[_P_HOST_NS] = pose.received_ns
            i[_P_HOST_CLOCK] = 1 if pose.host_frame_clock else 0
            f[:] = (*pose.pos_ned_m, *pose.vel_ned_mps, pose.yaw_rad)
        i[_P_SEQ] += 1

    def read_pose(self) -> tuple[bool, SharedPose | None]:
        """(consistent, pose): the newest pose (None: none), or (False, None) when every
        try met a write."""
        i, f = self._pose_i, self._pose_f
        for _ in range(_READ_TRIES):
            seq = int(i[_P_SEQ])
            if seq % 2:
                continue
            pose = None
            if i[_P_PRESENT]:
                v = [float(x) for x in f]
                pose = SharedPose(
                    pos_ned_m=(v[0], v[1], v[2]),
                    vel_ned_mps=(v[3], v[4], v[5]),
                    yaw_rad=v[6],
                    frame_ns=int(i[_P_FRAME_NS]),
                    received_ns=int(i[_P_HOST_NS]),
                    host_frame_clock=bool(i[_P_HOST_CLOCK]),
                )
            if int(i[_P_SEQ]) == seq:
                return True, pose
        return False, None

    # ---- the link: written by the main loop each pass when it changed --------------------
    def write_link(self, link: SharedLink) -> None:
        """The companion socket's peers (the first :data:`MAX_PEERS` IPv4 ones) and the
        main loop's signing timestamp."""
        if link == self._shared_link:
            return
        self._shared_link = link
        words = self._link
        peers = []
        for host, port in link.peers:
            with contextlib.suppress(OSError):
                peers.append((struct.unpack("!I", socket.inet_aton(host))[0], int(port)))
        peers = peers[:MAX_PEERS]
        words[_L_SEQ] += 1
        words[_L_FLOOR] = link.signing_floor
        words[_L_N] = len(peers)
        for k, (ip, port) in enumerate(peers):
            words[3 + 2 * k : 5 + 2 * k] = (ip, port)
        words[_L_SEQ] += 1

    def read_link(self) -> tuple[bool, SharedLink | None]:
        """(consistent, link), or (False, None) when every try met a write."""
        words = self._link
        for _ in range(_READ_TRIES):
            seq = int(words[_L_SEQ])
            if seq % 2:
                continue
            n = min(max(int(words[_L_N]), 0), MAX_PEERS)
            peers = tuple(
                (socket.inet_ntoa(struct.pack("!I", int(words[3 + 2 * k]) & 0xFFFFFFFF)),
                 int(words[4 + 2 * k]))
                for k in range(n)
            )  # fmt: skip
            floor = int(words[_L_FLOOR])
            if int(words[_L_SEQ]) == seq:
                return True, SharedLink(peers, floor)
        return False, None

    # ---- the reader hand-over and the sequence number ------------------------------------
    def set_main_reads(self, main_reads: bool) -> None:
        """The main loop: whether it reads the UDP socket itself (the process then stops
        reading it)."""
        self._control[_C_MAIN_READS] = 1 if main_reads else 0

    def main_reads(self) -> bool:
        return bool(self._control[_C_MAIN_READS])

    def set_alive_ns(self, now_ns: int) -> None:
        """The process: the host time [ns, monotonic] it ran its loop."""
        self._control[_C_ALIVE_NS] = now_ns

    def alive_ns(self) -> int:
        return int(self._control[_C_ALIVE_NS])

    def next_seq(self) -> int:
        """The MAVLink sequence number (0-255) of the companion's next frame, from either
        sender. Not atomic across the two processes: two sends in the same microseconds may
        both take one number, or send in the other order (the receiver counts a loss):
        measured 4 in 693 frames at 100 + 20 sends a second, against a loss counted at
        every interleaving with two counters."""
        words = self._control
        n = int(words[_C_SEQ])
        words[_C_SEQ] = n + 1
        return n % 256
