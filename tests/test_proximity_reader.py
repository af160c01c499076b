"""The OBSTACLE_DISTANCE process as the companion socket's only reader (issue 34): every
datagram reaches the main loop, in order, through a burst while the main loop reads
nothing; the process's pose stays fresh while the main loop is stopped (SIGSTOP), so the
sectors follow the moving vehicle; a SIGKILLed process hands the socket back to the main
loop at once, in a flight too (no telemetry hold); forged and unsigned poses are not
used; both senders share one MAVLink sequence counter.

The fake autopilot and the main loop are :mod:`test_proximity_process`'s."""

from __future__ import annotations

import contextlib
import json
import math
import os
import select
import signal
import socket
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from test_companion_sil import GOAL, _read_truth
from test_proximity_process import (
    HALF_M,
    KEY,
    POS,
    VOXEL_DIAG_M,
    WALL_N_M,
    _Autopilot,
    _MainLoop,
    _wait,
    _walled_map,
)

from companion.proximity.process import FORWARD_STALL_S
from companion.proximity.sectors import UINT16_MAX
from companion.proximity.sender import POSE_STALE_S
from companion.proximity.stream import snapshot_map
from protocols.signing import SigningKey, signing_timestamp_now

pytestmark = pytest.mark.processes

GROUND_STATION = (255, 190)


def _companion_port(main: _MainLoop) -> int:
    with socket.socket(fileno=os.dup(main.link.fileno())) as sock:
        return sock.getsockname()[1]


def test_a_burst_reaches_the_main_loop_whole_and_in_order_and_one_sequence_counter():
    """3000 datagrams from a ground station at 1500/s (six times an autopilot's 50 Hz ×
    4 streams) beside the autopilot's telemetry, while the main loop reads nothing for
    the 2 s: afterwards every one of both, each source in order; none dropped. The
    companion's frames (the main loop's heartbeats, the process's OBSTACLE_DISTANCE)
    carry one sequence of numbers."""
    ap = _Autopilot()
    main = _MainLoop(f"udpout:127.0.0.1:{ap.port}")
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs_mav = mavlink.MAVLink(None, srcSystem=GROUND_STATION[0], srcComponent=GROUND_STATION[1])
    burst = 3000
    try:
        main.start()
        main.heartbeat()
        assert _wait(lambda: len(ap.received) >= 3, 10.0)
        to = ("127.0.0.1", _companion_port(main))
        got, sent_before = [], ap.telemetry_sent
        for i in range(burst):  # the main loop does not read meanwhile
            msg = mavlink.MAVLink_named_value_int_message(i, b"burst", i)
            gcs.sendto(msg.pack(gcs_mav), to)
            if i % 15 == 14:
                main.heartbeat()
                time.sleep(0.01)
        ap.streaming.clear()
        time.sleep(0.1)
        telemetry = []
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and len(got) < burst:
            for msg in main.link.poll():
                if msg.get_type() == "NAMED_VALUE_INT":
                    got.append(msg.value)
                elif msg.get_type() == "LOCAL_POSITION_NED":
                    telemetry.append(msg)
            time.sleep(0.01)
        assert got == list(range(burst)), (len(got), main.process.figures())
        figures = main.process.figures()
        assert figures["forward_dropped"] == 0 and not figures["main_reads"], figures
        assert len(telemetry) >= (ap.telemetry_sent - sent_before) // 2 - 1
        # one counter for component 196: consecutive numbers at the autopilot, but for the
        # rare race (measured 689 of 693 steps over 6 s of 100 Hz main-loop sends); two
        # counters made every interleaving a jump (65 % consecutive in that measurement,
        # fewer here where the main loop sends less often)
        seqs = [f[4] for f in ap.frames if f[0] == 0xFD and (f[5], f[6]) == (1, 196)]
        steps = np.diff(seqs) % 256
        assert len(seqs) > 200 and np.mean(steps == 1) >= 0.95, np.unique(steps)
    finally:
        gcs.close()
        main.close()
        ap.close()


_MAIN_LOOP = """
import json, select, sys, time
from tests.test_proximity_process import HALF_M, POS, _MainLoop, _walled_map
from companion.proximity.stream import snapshot_map
main = _MainLoop("udpout:127.0.0.1:{port}")
main.start()
main.heartbeat()
main.process.set_map(snapshot_map(_walled_map(), POS[2], HALF_M, capture_ns=5_000_000))
print(main.process._proc.pid, flush=True)
while True:
    main.pass_(None)
    if select.select([sys.stdin], [], [], 0.01)[0]:
        line = sys.stdin.readline().strip()
        if line == "quit":
            break
        if line == "reset":
            main.process._shared.set_counter("pose_age_max_us", 0)
        figures = {{**main.process.figures(), "telemetry": main.telemetry}}
        print(json.dumps(figures), flush=True)
main.close()
"""


def _ask(parent: subprocess.Popen, line: str) -> dict:
    parent.stdin.write(line + "\n")
    parent.stdin.flush()
    ready = select.select([parent.stdout], [], [], 10.0)[0]
    assert ready, "the main loop did not answer"
    return json.loads(parent.stdout.readline())


def test_the_process_places_the_moving_vehicle_while_the_main_loop_is_stopped():
    """SIGSTOP the companion's main loop for 1.5 s while the vehicle flies north at
    1.5 m/s toward a wall: every OBSTACLE_DISTANCE meanwhile gives the distance ahead from
    where the vehicle is (none unknown), the process's pose was never older than 0.1 s,
    and the main loop, continued, reads every telemetry message of the stop."""
    ap = _Autopilot()
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    parent = subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(_MAIN_LOOP.format(port=ap.port))],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        env=env,
    )
    vel_n_mps = 1.5
    try:
        assert select.select([parent.stdout], [], [], 60.0)[0], "the main loop did not start"
        int(parent.stdout.readline())  # the process's pid: it is running
        assert _wait(lambda: any(m.time_usec == 5_000 for _, m, _ in ap.received), 10.0)
        reset_s = time.monotonic()
        before = _ask(parent, "reset")
        ap.fly(vel_n_mps)
        time.sleep(0.3)
        start = time.monotonic()
        os.kill(parent.pid, signal.SIGSTOP)
        time.sleep(1.5)
        os.kill(parent.pid, signal.SIGCONT)
        end = time.monotonic()
        after = _ask(parent, "figures")
        asked_s = time.monotonic()
        got = [(t, m) for t, m, _ in ap.received if start + 0.1 <= t <= end]
        assert len(got) >= 10 * 1.4 * 0.8, len(got)  # >= 10 Hz with slack for load
        telemetry_s = np.array(ap.telemetry_at)
        quiet_s = POSE_STALE_S - 0.08  # the stale age, less the process's read-to-send time
        for t, msg in got:
            if msg.distances[0] == UINT16_MAX:
                # only if this test's own autopilot thread (held off on a loaded machine) sent
                # no position for that long: the pose is stale, rightly
                last_s = telemetry_s[telemetry_s <= t].max()
                assert t - last_s > quiet_s, ("unknown while the main loop is stopped", t - last_s)
                continue
            expected_m = WALL_N_M - (ap.north_m(t) - POS[0])
            tol_m = VOXEL_DIAG_M + 0.1 + vel_n_mps * 0.1  # a voxel, and a pose 0.1 s old
            assert msg.distances[0] / 100.0 == pytest.approx(expected_m, abs=tol_m), t - start
        # None stale, unless this test's autopilot thread itself fell silent for over the
        # 0.5 s (less the 80 ms the process may take between reading and sending; a loaded
        # machine holds the pytest process off now and then): at most one send per 0.1 s
        # of such a silence.
        sent_s = [t for t in ap.telemetry_at if reset_s <= t <= asked_s]
        silences = np.diff([reset_s, *sent_s, asked_s])
        allowed = sum(math.floor((g - quiet_s) / 0.1) + 1 for g in silences if g > quiet_s)
        stale = after["stale_pose"] - before["stale_pose"]
        assert stale <= allowed, (stale, allowed, float(silences.max()), before, after)
        # Never older than the autopilot's longest silence in the window plus the 80 ms
        # the process may take between reading a position and sending (0.1 s at the
        # autopilot's 50 Hz). The silence is this test's thread, which a loaded machine
        # holds off now and then; the main loop's stopped copy would age by the full 1.5 s
        # (stale after 0.5 s, counted above).
        silence_s = float(silences.max())
        assert after["pose_age_max_s"] < silence_s + 0.08, (after, silence_s)
        assert after["own_pose"] > before["own_pose"] and after["alive"], after
        assert after["takeovers"] == 0  # the process read the socket throughout
        ap.streaming.clear()
        time.sleep(0.2)
        assert _wait(lambda: _ask(parent, "figures")["telemetry"] == ap.telemetry_sent, 5.0)
    finally:
        with contextlib.suppress(OSError):
            os.kill(parent.pid, signal.SIGCONT)
            parent.stdin.write("quit\n")
            parent.stdin.flush()
        try:
            parent.wait(timeout=10.0)
        except subprocess.TimeoutExpired:
            parent.kill()
            parent.wait(timeout=5.0)
        parent.stdin.close()
        parent.stdout.close()
        ap.close()


def test_a_killed_process_hands_the_socket_back_to_the_main_loop_at_once():
    """SIGKILL the process: the main loop reads the socket itself within a pass
    (bounded by FORWARD_STALL_S), telemetry never stops for longer than that, and at most
    the datagrams the process held when it died are lost."""
    ap = _Autopilot()
    main = _MainLoop(f"udpout:127.0.0.1:{ap.port}")
    arrivals: list[float] = []
    try:
        main.start()
        main.heartbeat()
        killed = switched = None
        passes = [time.monotonic()]  # this loop's passes: how long this process was held off
        deadline = passes[0] + 4.0
        while time.monotonic() < deadline:
            passes.append(time.monotonic())
            for msg in main.link.poll():
                if msg.get_type() == "LOCAL_POSITION_NED":
                    arrivals.append(time.monotonic())
            if killed is None and len(arrivals) >= 25:
                sent_at_kill = ap.telemetry_sent
                os.kill(main.process._proc.pid, signal.SIGKILL)
                killed = time.monotonic()
            if killed is not None and switched is None and not main.link.forwarded:
                switched = time.monotonic()
            time.sleep(0.01)
        assert killed is not None and switched is not None, main.process.figures()
        # This loop and the fake autopilot are threads of the test's process; on a loaded
        # machine it is held off now and then (0.5 s gap at load 28), which delays the
        # take-over and the telemetry alike: that hold-off, beyond the loop's 10 ms and the
        # autopilot's 20 ms, is measured and added.
        held_s = max(
            float(np.max(np.diff(passes))) - 0.01,
            float(np.max(np.diff(ap.telemetry_at))) - 0.02,
            0.0,
        )
        assert switched - killed <= FORWARD_STALL_S + held_s, (switched - killed, held_s)
        gaps = np.diff(arrivals)
        assert gaps.max() <= FORWARD_STALL_S + 0.1 + held_s, (gaps.max(), held_s)
        ap.streaming.clear()
        time.sleep(0.1)
        after = [m for m in main.link.poll() if m.get_type() == "LOCAL_POSITION_NED"]
        read = len(arrivals) + len(after)
        assert read >= ap.telemetry_sent // 2 - 2, (read, ap.telemetry_sent, sent_at_kill)
        assert main.process.figures()["main_reads"] and main.process.figures()["takeovers"] == 1
    finally:
        main.close()
        ap.close()


def test_forged_and_unsigned_poses_are_not_used_by_the_process():
    """The autopilot signs its telemetry; another sender floods the companion's port with
    LOCAL_POSITION_NED 4 m further north (1 m from the wall), unsigned and signed with the
    wrong key: the distance ahead stays the genuine one, and the refusals are counted."""
    ap = _Autopilot(KEY)
    main = _MainLoop(f"udpout:127.0.0.1:{ap.port}", KEY)
    liar = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    forged = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    forged.signing.secret_key = SigningKey(bytes(range(1, 33))).secret
    forged.signing.sign_outgoing = True
    forged.signing.timestamp = signing_timestamp_now(time.time() + 60.0)
    unsigned = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    try:
        main.start()
        main.heartbeat()
        main.process.set_map(snapshot_map(_walled_map(), POS[2], HALF_M, capture_ns=5_000_000))
        to = ("127.0.0.1", _companion_port(main))
        lie = mavlink.MAVLink_local_position_ned_message(0, POS[0] + 4.0, *POS[1:], 0, 0, 0)
        start = time.monotonic()
        while time.monotonic() - start < 1.5:
            for mav in (forged, unsigned):
                liar.sendto(lie.pack(mav), to)
            main.pass_(None)  # the main loop shares no pose: the process's own is used
            time.sleep(0.005)
        got = [m for t, m, _ in ap.received if t > start + 0.3 and m.time_usec == 5_000]
        assert len(got) >= 8, len(got)
        for msg in got:
            assert msg.distances[0] / 100.0 == pytest.approx(WALL_N_M, abs=VOXEL_DIAG_M + 0.1)
        figures = main.process.figures()
        assert figures["pose_refused"] >= 2 * 100 and figures["own_pose"] >= len(got), figures
        assert main.link.counters.signing_refused >= 2 * 100  # the main loop refused them too
    finally:
        liar.close()
        main.close()
        ap.close()


def test_a_flight_goes_on_when_the_process_is_killed(tmp_path):
    """The real companion flying the paper's scene in plant-sim: SIGKILL its
    OBSTACLE_DISTANCE process while it steers; the main loop reads the socket itself (said
    once), no telemetry hold, and the flight reaches its goal clear of the sphere."""
    import re

    from test_companion_sil import Rig

    rig = Rig(tmp_path)
    try:
        companion = rig.companion("--goal", *map(str, GOAL))
        rig.plant()
        found = re.search(r"OBSTACLE_DISTANCE process sending .*\(pid (\d+)", companion.logs())
        assert found, companion.logs()
        rig.wait_event(companion, "steering", 30)
        os.kill(int(found.group(1)), signal.SIGKILL)
        rig.wait_event(companion, "goal_reached", 120)
        logs = companion.stderr_text()  # all of it: logs() keeps only the tail
        assert logs.count("the main loop reads it itself") == 1, companion.logs()
        holds = [f for _, f in companion.events("hold")]
        assert not any("telemetry" in str(f.get("reason")) for f in holds), holds
        truth = _read_truth(rig.tmp / "run0" / "truth.csv")
        assert truth["surface_distance_m"].min() >= 0.35
    finally:
        rig.close()


def test_a_process_that_cannot_forward_stops_reading_and_the_main_loop_reads():
    """The forwarding stream breaks while the process lives (here: the main loop's end
    shut for reading, so the process's writes fail): the main loop reads the socket
    itself, the process no longer does (from then on the main loop gets every telemetry
    message) and keeps sending. (That the process closes its end, which is what tells the
    main loop when only the process sees the failure, is not observed here.)"""
    ap = _Autopilot()
    main = _MainLoop(f"udpout:127.0.0.1:{ap.port}")
    try:
        main.start()
        main.heartbeat()
        assert _wait(lambda: (main.pass_(None), main.telemetry)[1] >= 10, 10.0)
        main.process._reader._sock.shutdown(socket.SHUT_RD)
        assert _wait(lambda: (main.pass_(None), not main.link.forwarded)[1], 2.0)
        figures = main.process.figures()
        assert figures["alive"] and figures["main_reads"] and figures["takeovers"] == 1
        time.sleep(0.3)  # the process met the broken stream and stopped reading
        main.pass_(None)
        counted, sent = main.telemetry, ap.telemetry_sent
        sent_od = len(ap.received)
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline:
            main.pass_(None)
            time.sleep(0.01)
        ap.streaming.clear()
        time.sleep(0.1)
        main.pass_(None)
        assert main.telemetry - counted == ap.telemetry_sent - sent  # none taken elsewhere
        assert len(ap.received) - sent_od >= 7  # the process still sends (>= 10 Hz)
    finally:
        main.close()
        ap.close()
