"""Companion benchmark: frame capture → SET_POSITION_TARGET on the wire, max rate, CPU, RSS.

Runs ``python -m companion`` as a child against a minimal fake autopilot on UDP (PX4
flavour, already in OFFBOARD, so every processed frame yields a setpoint at once) and a
Zenoh publisher of pre-rendered stereo pairs of the paper's scene (obstacle in view).
Frames and telemetry are stamped with this host's monotonic clock (the fake autopilot's
``time_boot_ms`` is ``monotonic_ns() // 1e6``), so the setpoint's ``time_boot_ms`` equals
the capture millisecond of the frame that produced it, and the fake autopilot measures
capture → receipt on one clock.

Usage: ``.venv/bin/python benchmarks/bench_companion.py [--seconds 8]``
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import sys
import threading
import time
from pathlib import Path

import numpy as np
import zenoh
from pymavlink.dialects.v20 import ardupilotmega as mavlink

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from evaluation.sil import ChildProcess, free_port  # noqa: E402
from plant_sim.stereo_camera import StereoCameraRenderer  # noqa: E402
from plant_sim.world import paper_world  # noqa: E402
from protocols import stereo_frame  # noqa: E402
from protocols.camera import CameraModel  # noqa: E402
from protocols.frames import rotation_321  # noqa: E402
from protocols.keys import companion_status_key, stereo_key  # noqa: E402

POS = (15.0, 0.0, -7.0)  # 5 m from the obstacle centre, 3.5 m from its surface
YAW = np.pi


class FakeAutopilot:
    """UDP autopilot: heartbeat (PX4, OFFBOARD), 100 Hz pose; records setpoint receipts."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.005)
        self.port = self.sock.getsockname()[1]
        self.mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.parser = mavlink.MAVLink(None)
        self.parser.robust_parsing = True
        self.peer = None
        self.receipts: list[tuple[int, int]] = []  # (time_boot_ms, recv monotonic ns)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _send(self, msg) -> None:
        if self.peer is not None:
            self.sock.sendto(msg.pack(self.mav), self.peer)

    def _run(self) -> None:
        next_hb = next_pose = 0.0
        while not self.stop.is_set():
            try:
                data, addr = self.sock.recvfrom(65535)
                now_ns = time.monotonic_ns()
                self.peer = addr
                for msg in self.parser.parse_buffer(data) or []:
                    if msg.get_type() == "SET_POSITION_TARGET_LOCAL_NED":
                        self.receipts.append((msg.time_boot_ms, now_ns))
            except TimeoutError:
                pass
            now = time.monotonic()
            if now >= next_hb:
                next_hb = now + 1.0
                self._send(
                    mavlink.MAVLink_heartbeat_message(
                        mavlink.MAV_TYPE_QUADROTOR,
                        mavlink.MAV_AUTOPILOT_PX4,
                        mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
                        | mavlink.MAV_MODE_FLAG_SAFETY_ARMED,
                        6 << 16,
                        mavlink.MAV_STATE_ACTIVE,
                        3,
                    )
                )
            if now >= next_pose:
                next_pose = now + 0.01
                ms = time.monotonic_ns() // 1_000_000
                self._send(mavlink.MAVLink_local_position_ned_message(ms, *POS, 0, 0, 0))
                self._send(mavlink.MAVLink_attitude_message(ms, 0, 0, YAW, 0, 0, 0))


def _frames(width: int, height: int, n: int = 8):
    model = CameraModel() if width == 320 else CameraModel(width_px=width, height_px=height)
    renderer = StereoCameraRenderer(model)
    R = rotation_321(0.0, 0.0, YAW)
    return model.intrinsics, [
        renderer.render(paper_world(), np.array(POS), R, noise_seed=i) for i in range(n)
    ]


def _proc_cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _run(width, height, rate_hz, seconds, extra_args=()):
    ap = FakeAutopilot()
    ap.thread.start()
    zport = free_port(socket.SOCK_STREAM)
    ep = f"tcp/127.0.0.1:{zport}"
    child = ChildProcess(
        "companion",
        "companion",
        [
            "--mavlink",
            f"udpout:127.0.0.1:{ap.port}",
            "--zenoh-listen",
            ep,
            "--goal",
            "0",
            "0",
            "-7",
            "--log-level",
            "WARNING",
            *extra_args,
        ],
    )
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", json.dumps([ep]))
    statuses = []
    try:
        child.wait_line(r"^COMPANION READY", 60)
        intr, renders = _frames(width, height)
        with zenoh.open(conf) as session:
            sub = session.declare_subscriber(
                companion_status_key("sim1"), lambda s: statuses.append(time.monotonic_ns())
            )
            pub = session.declare_publisher(stereo_key("sim1"))
            child.wait_line(r"COMPANION EVENT phase", 15)
            published, mark, n0, cpu = _publish(
                pub, child, intr, renders, rate_hz, seconds, statuses
            )
            rss = _rss_mb(child.proc.pid)
            time.sleep(0.3)
            processed = len(statuses) - n0
            sub.undeclare()
            pub.undeclare()
    finally:
        child.stop()
        ap.stop.set()
        ap.thread.join(timeout=2)
        ap.sock.close()
        child.close()
    return _summary(width, height, rate_hz, published[mark:], ap.receipts, processed, cpu, rss)


def _publish(pub, child, intr, renders, rate_hz, seconds, statuses):
    """Publish frames at ``rate_hz`` for a warm-up second and then ``seconds``, stamped with
    this host's monotonic clock; returns (capture stamps, index of the first measured one,
    statuses before the measured window, the companion's CPU use in cores over it)."""
    period = 1.0 / rate_hz
    published = []
    t_next = time.monotonic()
    t_end = t_next + 1.0 + seconds
    cpu0 = None
    seq = 0
    while time.monotonic() < t_end:
        if cpu0 is None and time.monotonic() > t_end - seconds:
            cpu0, w0, n0 = _proc_cpu_s(child.proc.pid), time.monotonic(), len(statuses)
            mark = len(published)
        r = renders[seq % len(renders)]
        cap = time.monotonic_ns()
        frame = stereo_frame.StereoFrame(seq, cap, intr, r.left, r.right)
        pub.put(stereo_frame.encode(frame))
        published.append(cap)
        seq += 1
        t_next += period
        time.sleep(max(0.0, t_next - time.monotonic()))
    cpu = (_proc_cpu_s(child.proc.pid) - cpu0) / (time.monotonic() - w0)
    return published, mark, n0, cpu


def _summary(width, height, rate_hz, measured, receipts, processed, cpu, rss):
    """Latency from capture to setpoint on the wire (setpoints caused by a frame carry its
    capture millisecond), throughput, CPU and memory of one run."""
    caps_ms = {c // 1_000_000: c for c in measured}
    lat = [(recv - caps_ms[ms]) * 1e-6 for ms, recv in receipts if ms in caps_ms]
    n_pub = len(measured)
    return {
        "size": f"{width}x{height}",
        "rate_hz": rate_hz,
        "published": n_pub,
        "processed": processed,
        "processed_fraction": round(processed / max(1, n_pub), 3),
        "latency_p50_ms": round(float(np.percentile(lat, 50)), 2) if lat else None,
        "latency_p99_ms": round(float(np.percentile(lat, 99)), 2) if lat else None,
        "setpoints_matched": len(lat),
        "cpu_cores": round(cpu, 2),
        "rss_mb": round(rss, 1),
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--seconds", type=float, default=6.0)
    args = p.parse_args()
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    print("capture → SET_POSITION_TARGET on the wire, 320x240 at 30 Hz:")
    r = _run(320, 240, 30.0, args.seconds)
    print(json.dumps(r))
    for w, h, rates, extra in (
        (320, 240, (60, 90, 120), ()),
        (640, 480, (30, 45, 60), ()),
    ):
        best = None
        for rate in rates:
            r = _run(w, h, float(rate), args.seconds, extra)
            print(json.dumps(r))
            if r["processed_fraction"] >= 0.95:
                best = rate
        print(f"highest sustained rate at {w}x{h}: {best or '< ' + str(rates[0])} Hz")
    return 0


if __name__ == "__main__":
    sys.exit(main())
