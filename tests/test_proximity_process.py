"""OBSTACLE_DISTANCE from a process of its own (issue 34): the shared block gives the live
map's sectors, the pose and the link; the process sends through the companion's own
socket (the autopilot sees one peer), forwards every datagram it reads there to the main
loop (test_proximity_reader.py has the rest of that), keeps >= 10 Hz while the
companion's interpreter is held, places the vehicle from the pose the main loop shares
(all unknown once it is older than 0.5 s), signs as its own link no lower than the main
loop, dies with the companion and says when it ended.

A fake autopilot on 127.0.0.1 (a bound UDP socket that, like the fuzz test's, answers only
the first peer that wrote to it) streams LOCAL_POSITION_NED and ATTITUDE; the test plays
the companion's main loop (:class:`_MainLoop`: its link, the shares the service makes)."""

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
from companion.link.connection import MavlinkConnection
from companion.proximity.process import (
    SIGNING_LINK_ID,
    ProcessSpec,
    ProximityProcess,
    own_process_refusal,
)
from companion.proximity.sectors import UINT16_MAX, ProximityConfig, sectors_from_map
from companion.proximity.sender import ProximitySender
from companion.proximity.shared import SharedLink, SharedMap, SharedPose
from companion.proximity.stream import SLAB_MARGIN_M, snapshot_map
from protocols.signing import SignatureVerifier, SigningKey, signing_timestamp_now

pytestmark = pytest.mark.processes

POS = np.array([3.0, -2.0, -7.0])
CFG = ProximityConfig()
WALL_N_M = 5.0
HALF_M = CFG.band_half_height_m + CFG.unseen_extension_m + SLAB_MARGIN_M
VOXEL_DIAG_M = 0.4 * math.sqrt(2.0)  # the far layer's footprint: the sectoring's resolution
COMPANION = (1, 196)
KEY = SigningKey(bytes(range(32)))
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)  # Linux; not exported by Python
AHEAD_S = 30.0  # the signing autopilot's clock runs this far ahead of ours


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


def _pose(north_m: float, vel_n_mps: float, received_ns: int) -> SharedPose:
    return SharedPose(
        pos_ned_m=(north_m, POS[1], POS[2]),
        vel_ned_mps=(vel_n_mps, 0.0, 0.0),
        yaw_rad=0.0,
        frame_ns=received_ns,
        received_ns=received_ns,
        host_frame_clock=False,
    )


def test_the_shared_block_gives_the_live_map_the_pose_and_the_link():
    space = _walled_map()
    writer = SharedMap(space.config)
    reader = SharedMap(space.config, writer.name)
    try:
        assert reader.read() == (True, None)  # nothing written yet: no map
        assert reader.read_pose() == (True, None)
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
        pose = SharedPose((1.5, -2.0, -7.25), (8.0, 0.5, -0.25), 0.75, 123, 456, True)
        writer.write_pose(pose)
        assert reader.read_pose() == (True, pose)
        writer.write_pose(None)
        assert reader.read_pose() == (True, None)
        link = SharedLink((("127.0.0.1", 14550), ("10.1.2.3", 65535)), 2**47 + 5)
        writer.write_link(link)
        assert reader.read_link() == (True, link)
    finally:
        reader.close()
        writer.close()


def test_udp_links_get_a_process_and_other_links_are_told_why_not():
    for url in ("udpout:127.0.0.1:14550", "udpin:0.0.0.0:14550", "udp:127.0.0.1:14550"):
        assert own_process_refusal(url) is None, url
    for url in ("tcp:127.0.0.1:5760", "/dev/ttyS0", "udpbcast:255.255.255.255:14550"):
        assert "not a UDP socket" in own_process_refusal(url), url


class _Autopilot:
    """A bound UDP socket that answers only the first peer that wrote to it: every 20 ms
    LOCAL_POSITION_NED and ATTITUDE (signed ``AHEAD_S`` ahead with ``key``); keeps each
    OBSTACLE_DISTANCE with its kernel arrival time and the raw frame, and every peer."""

    def __init__(self, key: SigningKey | None = None) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", _free_port()))
        # the kernel's arrival time: this test's own thread may be held off the interpreter
        self.sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        self.sock.settimeout(0.02)
        self.port = self.sock.getsockname()[1]
        self.mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        if key is not None:
            self.mav.signing.secret_key = key.secret
            self.mav.signing.sign_outgoing = True
            self.mav.signing.timestamp = signing_timestamp_now(time.time() + AHEAD_S)
        self.parser = mavlink.MAVLink(None)
        self.parser.robust_parsing = True
        self.received: list[tuple[float, object, bytes]] = []
        self.frames: list[bytes] = []  # every frame from the companion, in arrival order
        self.peers: list = []
        self.telemetry_sent = 0
        self.telemetry_at: list[float] = []  # when each LOCAL_POSITION_NED left [s monotonic]
        self.vel_n_mps = 0.0  # fly(): north at this speed from POS
        self.t0: float | None = None
        self.streaming = threading.Event()
        self.streaming.set()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        next_s = time.monotonic()
        while not self._stop.is_set():
            try:
                data, anc, _, addr = self.sock.recvmsg(65535, 64)
                if addr not in self.peers:
                    self.peers.append(addr)
                arrived = _arrival_monotonic(anc)
                self.frames.append(data)
                for msg in self.parser.parse_buffer(data) or []:
                    if msg.get_type() == "OBSTACLE_DISTANCE":
                        self.received.append((arrived, msg, data))
            except TimeoutError:
                pass
            now = time.monotonic()
            if now >= next_s and self.peers and self.streaming.is_set():
                next_s = now + 0.02
                north = self.north_m(now)
                pos = mavlink.MAVLink_local_position_ned_message(
                    0, north, *POS[1:], self.vel_n_mps if self.t0 else 0.0, 0.0, 0.0
                )
                att = mavlink.MAVLink_attitude_message(0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
                for m in (pos, att):
                    self.sock.sendto(m.pack(self.mav), self.peers[0])
                    self.telemetry_sent += 1
                self.telemetry_at.append(now)

    def fly(self, vel_n_mps: float) -> None:
        """From now on, the telemetry's vehicle flies north at ``vel_n_mps`` from POS."""
        self.vel_n_mps, self.t0 = vel_n_mps, time.monotonic()

    def north_m(self, t_s: float) -> float:
        """The vehicle's north at monotonic time ``t_s`` [m]."""
        return POS[0] + (0.0 if self.t0 is None else self.vel_n_mps * max(t_s - self.t0, 0.0))

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


class _MainLoop:
    """The companion's side as the service runs it: its link (opened, a heartbeat sent),
    the process forked with that link's socket, and the shares of each pass."""

    def __init__(self, url: str, key: SigningKey | None = None) -> None:
        self.link = MavlinkConnection(
            url, system_id=COMPANION[0], component_id=COMPANION[1], signing_key=key
        )
        self.link.open()
        self.process = ProximityProcess(ProximitySender(CFG), _spec(self.link, key))
        self.telemetry = 0

    def link_state(self) -> SharedLink:
        return SharedLink(tuple(self.link.udp_peers() or ()), self.link.signing_timestamp)

    def start(self) -> None:
        self.process.start(self.link_state())
        assert self.process.wait_ready(), self.process.figures()
        self.link.forward_from(self.process)  # as the service does
        self.link.seq_source = self.process.next_seq

    def heartbeat(self) -> None:
        self.link.send(mavlink.MAVLink_heartbeat_message(18, 8, 0, 0, 0, 3))

    def pass_(self, pose: SharedPose | None) -> None:
        """Read the link (the only reader), then share the pose and the link."""
        for msg in self.link.poll():
            self.telemetry += msg.get_type() in ("LOCAL_POSITION_NED", "ATTITUDE")
        self.process.share(pose, self.link_state())

    def close(self) -> None:
        self.process.close()
        self.link.close()


def _spec(link: MavlinkConnection, key: SigningKey | None = None) -> ProcessSpec:
    return ProcessSpec(
        proximity=CFG,
        space=KnownSpaceConfig(),
        link_fd=link.fileno(),
        system_id=COMPANION[0],
        component_id=COMPANION[1],
        signing_secret=None if key is None else key.secret,
        parent_pid=0,
    )


def _wait(cond, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.01)
    return cond()


def _free_port(kind: int = socket.SOCK_DGRAM) -> int:
    """:func:`evaluation.sil.free_port`, imported when called: the main loop that
    :mod:`test_proximity_reader` starts in a process of its own imports this module, and
    the evaluation package (plant_sim, python-control, scipy) took 24 s of its start at
    load 17 on two cores, past the test's 60 s once."""
    from evaluation.sil import free_port

    return free_port(kind)


def _spin_holding_the_gil(seconds: float) -> None:
    """Pure Python for ``seconds``: the interpreter lock is this thread's all along, as a
    numba kernel without ``nogil`` holds it."""
    end = time.monotonic() + seconds
    x = 0
    while time.monotonic() < end:
        x += 1


def test_the_process_sends_through_the_companions_socket_at_rate_and_places_the_vehicle():
    """One peer at the autopilot, every telemetry message read by the main loop, >= 10 Hz
    while the interpreter is held, the distance ahead from the pose carried forward (the
    process's own: the telemetry it reads flies as the shared pose does), and all unknown
    once that pose is older than 0.5 s."""
    ap = _Autopilot()
    main = _MainLoop(f"udpout:127.0.0.1:{ap.port}")
    vel_n_mps = 0.3  # at most 3 m in the waits below: short of the wall
    try:
        main.start()
        main.heartbeat()  # the autopilot answers this port (the process's sends come from it)
        t0_ns = time.monotonic_ns()
        ap.fly(vel_n_mps)  # the telemetry the process reads flies as the shared pose does

        def north_m(t_ns: float) -> float:
            return POS[0] + vel_n_mps * (t_ns - t0_ns) * 1e-9

        main.process.set_map(snapshot_map(_walled_map(), POS[2], HALF_M, capture_ns=5_000_000))
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and not (
            len(ap.received) > 5 and ap.received[-1][1].time_usec == 5_000
        ):  # the main loop's passes, sharing the vehicle's pose as it flies north
            now_ns = time.monotonic_ns()
            main.pass_(_pose(north_m(now_ns), vel_n_mps, now_ns))
            time.sleep(0.01)
        assert ap.received and ap.received[-1][1].time_usec == 5_000, len(ap.received)
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
        # before the spin: the distance ahead is from the pose carried forward to the send
        # (to a voxel). The last send before it whose telemetry was flowing: this test's
        # autopilot thread, held off the CPU on a loaded machine, may have let the pose
        # go stale (all unknown, rightly) just before the spin.
        sent_at = np.array(ap.telemetry_at)

        def fresh(t: float) -> bool:  # a position left the autopilot < 0.4 s before
            return bool(np.any((sent_at <= t) & (sent_at > t - 0.4)))

        t, msg = next((t, m) for t, m, _ in reversed(ap.received) if t < start and fresh(t))
        assert msg.time_usec == 5_000
        expected_m = WALL_N_M - (north_m(t * 1e9) - POS[0])
        assert msg.distances[0] / 100.0 == pytest.approx(expected_m, abs=VOXEL_DIAG_M + 0.1)
        # during the spin no pass shared a pose: older than 0.5 s, every sector unknown
        stale = [m for t, m in got if t > start + 0.6]
        assert stale and all(set(m.distances) == {UINT16_MAX} for m in stale)
        figures = main.process.figures()
        assert figures["alive"] and figures["errors"] == 0 and figures["stale_pose"] > 0
        assert figures["realtime"] == _may_be_realtime()
        # one peer: the companion's port; and the main loop has every telemetry message
        ap.streaming.clear()
        time.sleep(0.1)
        main.pass_(None)
        assert _wait(lambda: (main.pass_(None), main.telemetry)[1] == ap.telemetry_sent, 2.0)
        assert len(ap.peers) == 1, ap.peers
    finally:
        main.close()
        ap.close()
    assert main.process.figures()["sent"] >= figures["sent"]  # exit statistics, after close


def test_the_process_signs_as_its_own_link_never_below_the_main_loop():
    """Link id 1 beside the main loop's 0, both streams accepted in arrival order; the
    process's timestamps follow the main loop's, which follows the autopilot's (30 s
    ahead here): an autopilot whose clock is 80 s ahead of ours (more than a new stream's
    minute) still accepts the process's stream as it accepts the main loop's."""
    ap = _Autopilot(KEY)
    main = _MainLoop(f"udpout:127.0.0.1:{ap.port}", KEY)
    try:
        main.start()
        main.heartbeat()
        assert _wait(lambda: (main.pass_(None), main.telemetry)[1] >= 4, 10.0)
        floor = main.link.signing_timestamp
        assert floor >= signing_timestamp_now(time.time() + AHEAD_S - 5.0)
        main.heartbeat()
        assert _wait(lambda: _signed_since(ap, floor) >= 3, 10.0)
        frames = [f for f in ap.frames if f[0] == 0xFD]
        verifier = SignatureVerifier(KEY)
        assert [verifier.verify(f) for f in frames] == [None] * len(frames)
        link_ids = {f[-13] for f in frames}
        assert link_ids == {0, SIGNING_LINK_ID}
        for _, msg, frame in ap.received:
            assert frame[2] & 0x01, "unsigned"  # MAVLINK_IFLAG_SIGNED
            assert frame[-13] == SIGNING_LINK_ID  # link id, then 6 timestamp, 6 signature
            assert (msg.get_srcSystem(), msg.get_srcComponent()) == COMPANION
        ahead = SignatureVerifier(KEY, clock_unix_s=lambda: time.time() + 80.0)
        latest = [f for _, _, f in ap.received][-1]
        assert _timestamp(latest) > floor and ahead.verify(latest) is None
    finally:
        main.close()
        ap.close()


def _timestamp(frame: bytes) -> int:
    tlow, thigh = struct.unpack_from("<IH", frame, len(frame) - 12)
    return tlow | (thigh << 32)


def _signed_since(ap: _Autopilot, floor: int) -> int:
    """OBSTACLE_DISTANCE frames signed at or after ``floor``."""
    return sum(_timestamp(f) >= floor for _, _, f in ap.received)


def test_on_a_udpin_link_the_process_sends_to_the_peers_the_main_loop_heard():
    """``udpin``: no peer until the autopilot writes (counted, nothing sent); then the
    process answers it from the companion's port."""
    port = _free_port()
    main = _MainLoop(f"udpin:127.0.0.1:{port}")
    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer.settimeout(5.0)
    try:
        main.start()
        assert _wait(lambda: main.process.figures()["no_peer"] >= 2, 5.0)
        assert main.process.figures()["sent"] == 0
        hb = mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 0, 3)
        peer.sendto(
            hb.pack(mavlink.MAVLink(None, srcSystem=1, srcComponent=1)), ("127.0.0.1", port)
        )
        assert _wait(lambda: (main.pass_(None), main.link.udp_peers())[1], 5.0)
        parser = mavlink.MAVLink(None)
        data, addr = peer.recvfrom(65535)
        assert addr == ("127.0.0.1", port)
        assert parser.parse_buffer(data)[0].get_type() == "OBSTACLE_DISTANCE"
    finally:
        peer.close()
        main.close()


def test_the_process_dies_with_the_companion_and_its_end_is_reported():
    ap = _Autopilot()
    parent_code = textwrap.dedent(
        f"""
        import sys, time
        from tests.test_proximity_process import _MainLoop
        main = _MainLoop("udpout:127.0.0.1:{ap.port}")
        main.start()
        main.heartbeat()
        print(main.process._proc.pid, flush=True)
        time.sleep(60)
        """
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    parent = subprocess.Popen(
        [sys.executable, "-c", parent_code], stdout=subprocess.PIPE, text=True, env=env
    )
    try:
        line = parent.stdout.readline()  # bounded: the parent's start() waits at most 30 s
        child_pid = int(line)
        assert _wait(lambda: len(ap.received) >= 3, 10.0)
        parent.send_signal(signal.SIGKILL)
        parent.wait(timeout=5.0)
        assert _wait(lambda: not _alive(child_pid), 5.0), "an orphan OBSTACLE_DISTANCE process"
    finally:
        if parent.poll() is None:
            parent.kill()
        parent.stdout.close()
    main = _MainLoop(f"udpout:127.0.0.1:{ap.port}")
    try:
        main.start()
        stream = main.process
        assert stream.check() is None
        os.kill(stream._proc.pid, signal.SIGKILL)
        assert _wait(lambda: not stream.figures()["alive"], 5.0)
        reason = stream.check()
        assert reason is not None and "ended" in reason
        assert stream.check() is None  # said once
        assert stream.figures()["errors"] == 1
    finally:
        main.close()
        ap.close()


def test_a_sigkilled_companion_leaves_no_obstacle_distance_process():
    """The real companion, default configuration, on a ``udpout`` link: it forks the
    process; SIGKILL the companion and the process is gone within 5 s."""
    import re

    from evaluation.sil import ChildProcess

    ap = _Autopilot()
    zenoh = f"tcp/127.0.0.1:{_free_port(socket.SOCK_STREAM)}"
    companion = ChildProcess(
        "companion",
        "companion",
        ["--mavlink", f"udpout:127.0.0.1:{ap.port}", "--zenoh-listen", zenoh,
         "--no-request-mode"],
    )  # fmt: skip
    try:
        companion.wait_line(r"^COMPANION READY ", 60)
        found = re.search(r"OBSTACLE_DISTANCE process sending .*\(pid (\d+)", companion.logs())
        assert found, companion.logs()
        child_pid = int(found.group(1))
        assert _wait(lambda: len(ap.received) >= 3, 10.0), companion.logs()
        assert len(ap.peers) == 1, ap.peers  # the process writes from the companion's port
        companion.proc.send_signal(signal.SIGKILL)
        companion.proc.wait(timeout=5.0)
        assert _wait(lambda: not _alive(child_pid), 5.0), "an orphan OBSTACLE_DISTANCE process"
    finally:
        companion.stop()
        print(companion.logs())  # shown only when the test fails
        companion.close()
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
