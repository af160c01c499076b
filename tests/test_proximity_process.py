"""OBSTACLE_DISTANCE from a process of its own (issue 34): the shared map gives the live
map's sectors, the process keeps >= 10 Hz while the companion's interpreter is held,
places the vehicle from its own socket's telemetry, signs as its own link, dies with the
companion and says when it ended.

A fake autopilot on 127.0.0.1 (a bound UDP socket that answers every peer, as plant-sim's
``udpin`` and ArduPilot's UDP ports do) streams LOCAL_POSITION_NED and ATTITUDE."""

from __future__ import annotations

import math
import os
import signal
import socket
import struct
import subprocess
import sys
import textwrap
import threading
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.known_space import FREE, OCCUPIED, KnownSpace, KnownSpaceConfig
from companion.proximity.process import (
    SIGNING_LINK_ID,
    ProcessSpec,
    ProximityProcess,
    SharedMap,
    own_process_possible,
)
from companion.proximity.sectors import ProximityConfig, sectors_from_map
from companion.proximity.sender import ProximitySender
from companion.proximity.stream import SLAB_MARGIN_M, snapshot_map
from evaluation.sil import free_port
from protocols.signing import SigningKey

pytestmark = pytest.mark.processes

POS = np.array([3.0, -2.0, -7.0])
CFG = ProximityConfig()
WALL_N_M = 5.0
HALF_M = CFG.band_half_height_m + CFG.unseen_extension_m + SLAB_MARGIN_M
VOXEL_DIAG_M = 0.4 * math.sqrt(2.0)  # the far layer's footprint: the sectoring's resolution
COMPANION = (1, 196)
KEY = SigningKey(bytes(range(32)))
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)  # Linux; not exported by Python


def _walled_map() -> KnownSpace:
    space = KnownSpace(KnownSpaceConfig())
    space.mark_vehicle(POS)
    for layer in (space, space.far):
        layer.grid[:] = FREE
        v = layer.config.voxel_m
        north = (np.arange(layer.grid.shape[0]) + layer.origin_vox[0]) * v
        layer.grid[north + v > POS[0] + WALL_N_M] = OCCUPIED
    space.frames = 1
    return space


def test_the_shared_map_gives_the_sectors_of_the_live_map():
    space = _walled_map()
    writer = SharedMap(space.config)
    reader = SharedMap(space.config, writer.name)
    try:
        assert reader.read() == (True, None)  # nothing written yet: no map
        writer.write(snapshot_map(space, POS[2], HALF_M, capture_ns=42))
        ok, snap = reader.read()
        assert ok and snap is not None and snap.far is not None
        assert snap.capture_ns == 42 and snap.frames == 1
        for yaw_deg in (0.0, 30.0, 200.0):
            live = sectors_from_map(space, POS, math.radians(yaw_deg), CFG)
            copy = sectors_from_map(snap, POS, math.radians(yaw_deg), CFG)
            np.testing.assert_array_equal(copy.distances_cm, live.distances_cm)
        writer.header[0] += 1  # a writer stopped half-way (odd sequence): not read
        assert reader.read() == (False, None)
        writer.header[0] += 1
        writer.write(None)
        assert reader.read() == (True, None)
        writer.write_clock(1.25, 7_000)
        assert reader.clock() == (1.25, 7_000)
    finally:
        reader.close()
        writer.close()


def test_only_udpout_links_get_a_process():
    assert own_process_possible("udpout:127.0.0.1:14550")
    for url in ("udpin:0.0.0.0:14550", "udp:127.0.0.1:14550", "tcp:127.0.0.1:5760", "/dev/ttyS0"):
        assert not own_process_possible(url), url


class _Autopilot:
    """A bound UDP socket: every 20 ms LOCAL_POSITION_NED (moving north at ``vel_n_mps``)
    and ATTITUDE to every peer that wrote; keeps each OBSTACLE_DISTANCE it receives with its
    receipt time and the raw frame."""

    def __init__(self, vel_n_mps: float) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", free_port()))
        # the kernel's arrival time: this test's own thread may be held off the interpreter
        self.sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        self.sock.settimeout(0.02)
        self.port = self.sock.getsockname()[1]
        self.vel_n_mps = vel_n_mps
        self.mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.parser = mavlink.MAVLink(None)
        self.parser.robust_parsing = True
        self.received: list[tuple[float, object, bytes]] = []
        self.peers: set = set()
        self.t0 = time.monotonic()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def north_m(self, t: float) -> float:
        return POS[0] + self.vel_n_mps * (t - self.t0)

    def _run(self) -> None:
        next_s = time.monotonic()
        while not self._stop.is_set():
            try:
                data, anc, _, addr = self.sock.recvmsg(65535, 64)
                self.peers.add(addr)
                arrived = _arrival_monotonic(anc)
                for msg in self.parser.parse_buffer(data) or []:
                    if msg.get_type() == "OBSTACLE_DISTANCE":
                        self.received.append((arrived, msg, data))
            except TimeoutError:
                pass
            now = time.monotonic()
            if now >= next_s:
                next_s = now + 0.02
                pos = mavlink.MAVLink_local_position_ned_message(
                    0, self.north_m(now), POS[1], POS[2], self.vel_n_mps, 0.0, 0.0
                )
                att = mavlink.MAVLink_attitude_message(0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
                for addr in list(self.peers):
                    for m in (pos, att):
                        self.sock.sendto(m.pack(self.mav), addr)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.sock.close()


def _arrival_monotonic(ancillary) -> float:
    """The datagram's kernel arrival time (SO_TIMESTAMPNS, wall clock) on the monotonic
    clock [s]."""
    for level, kind, data in ancillary:
        if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS:
            sec, nsec = struct.unpack("qq", data[:16])
            return sec + nsec * 1e-9 - time.time() + time.monotonic()
    return time.monotonic()


def _spec(port: int, key: SigningKey | None = None) -> ProcessSpec:
    return ProcessSpec(
        proximity=CFG,
        space=KnownSpaceConfig(),
        url=f"udpout:127.0.0.1:{port}",
        system_id=COMPANION[0],
        component_id=COMPANION[1],
        baud=921600,
        signing_secret=None if key is None else key.secret,
        autopilot=(1, 1),
        parent_pid=0,
    )


def _wait(cond, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.01)
    return cond()


def _spin_holding_the_gil(seconds: float) -> None:
    """Pure Python for ``seconds``: the interpreter lock is this thread's all along, as a
    numba kernel without ``nogil`` holds it."""
    end = time.monotonic() + seconds
    x = 0
    while time.monotonic() < end:
        x += 1


def test_the_process_keeps_the_rate_while_the_companion_is_busy_and_places_the_vehicle():
    ap = _Autopilot(vel_n_mps=0.3)  # at most 3 m in the 10 s waits below: short of the wall
    stream = ProximityProcess(ProximitySender(CFG), _spec(ap.port))
    try:
        stream.start()
        assert stream.wait_ready(), stream.figures()
        ap.t0 = time.monotonic()  # the vehicle sets off from POS now
        stream.set_map(snapshot_map(_walled_map(), POS[2], HALF_M, capture_ns=5_000_000))
        assert _wait(lambda: ap.received and ap.received[-1][1].time_usec == 5_000, 10.0)
        start = time.monotonic()
        sys.setswitchinterval(5.0)  # no other thread of this process runs meanwhile
        try:
            _spin_holding_the_gil(1.5)
        finally:
            sys.setswitchinterval(0.005)
        end = time.monotonic()
        assert _wait(lambda: ap.received[-1][0] > end, 5.0)  # the thread read them all
        got = [(t, m) for t, m, _ in ap.received if start <= t <= end]
        times = np.array([t for t, _ in got])
        assert times.size >= 10 * 1.5 * 0.8, times.size  # >= 10 Hz, with slack for load
        assert np.max(np.diff(times)) < 0.5, np.diff(times)  # the autopilots' timeout
        # the distance ahead is from where the autopilot said the vehicle is (to a voxel);
        # before the spin (the fake autopilot is a thread of this process: during it, no
        # telemetry, and after 0.5 s the process rightly sends unknown)
        t, msg = next((t, m) for t, m, _ in reversed(ap.received) if t < start)
        assert msg.time_usec == 5_000
        expected_m = WALL_N_M - (ap.north_m(t) - POS[0])
        assert msg.distances[0] / 100.0 == pytest.approx(expected_m, abs=VOXEL_DIAG_M + 0.1)
        figures = stream.figures()
        assert figures["alive"] and figures["errors"] == 0 and figures["telemetry"] > 0
        assert figures["realtime"] == _may_be_realtime()
    finally:
        stream.close()
        ap.close()
    assert stream.figures()["sent"] >= figures["sent"]  # the exit statistics, after close


def test_the_process_signs_as_its_own_link():
    ap = _Autopilot(vel_n_mps=0.0)
    stream = ProximityProcess(ProximitySender(CFG), _spec(ap.port, KEY))
    try:
        stream.start()
        assert stream.wait_ready(), stream.figures()
        assert _wait(lambda: len(ap.received) >= 3, 10.0)
        for _, msg, frame in ap.received[:3]:
            assert frame[2] & 0x01, "unsigned"  # MAVLINK_IFLAG_SIGNED
            assert frame[-13] == SIGNING_LINK_ID  # link id, then 6 timestamp, 6 signature
            assert (msg.get_srcSystem(), msg.get_srcComponent()) == COMPANION
    finally:
        stream.close()
        ap.close()


def test_the_process_dies_with_the_companion_and_its_end_is_reported():
    ap = _Autopilot(vel_n_mps=0.0)
    parent_code = textwrap.dedent(
        f"""
        import sys, time
        from tests.test_proximity_process import CFG, _spec
        from companion.proximity.process import ProximityProcess
        from companion.proximity.sender import ProximitySender
        p = ProximityProcess(ProximitySender(CFG), _spec({ap.port}))
        p.start()
        assert p.wait_ready()
        print(p._proc.pid, flush=True)
        time.sleep(60)
        """
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    parent = subprocess.Popen(
        [sys.executable, "-c", parent_code], stdout=subprocess.PIPE, text=True, env=env
    )
    try:
        line = parent.stdout.readline()  # bounded: the parent's start() waits at most 60 s
        child_pid = int(line)
        assert _wait(lambda: len(ap.received) >= 3, 10.0)
        parent.send_signal(signal.SIGKILL)
        parent.wait(timeout=5.0)
        assert _wait(lambda: not _alive(child_pid), 5.0), "an orphan OBSTACLE_DISTANCE process"
    finally:
        if parent.poll() is None:
            parent.kill()
        parent.stdout.close()
    stream = ProximityProcess(ProximitySender(CFG), _spec(ap.port))
    try:
        stream.start()
        assert stream.wait_ready(), stream.figures()
        assert stream.check() is None
        os.kill(stream._proc.pid, signal.SIGKILL)
        assert _wait(lambda: not stream.figures()["alive"], 5.0)
        reason = stream.check()
        assert reason is not None and "ended" in reason
        assert stream.check() is None  # said once
        assert stream.figures()["errors"] == 1
    finally:
        stream.close()
        ap.close()


def _may_be_realtime() -> bool:
    """Whether a process of this user may take SCHED_FIFO (probed in a child of its own)."""
    probe = "import os; os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))"
    return subprocess.run([sys.executable, "-c", probe], capture_output=True).returncode == 0


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split()[2] != "Z"
    except FileNotFoundError:
        return False
