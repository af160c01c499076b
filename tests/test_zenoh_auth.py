"""Zenoh access control: with the shipped auth configs, only authenticated peers' frames
reach the companion (issue 10). Real companion process, Zenoh sessions on 127.0.0.1."""

from __future__ import annotations

import json
import socket
import time
from pathlib import Path

import numpy as np
import zenoh

from evaluation.sil import ChildProcess, free_port
from protocols import stereo_frame
from protocols.camera import StereoIntrinsics
from protocols.keys import stereo_key

REPO = Path(__file__).resolve().parents[1]
ZENOH_CONFIGS = REPO / "docker" / "config" / "zenoh"
N_FRAMES = 20


def _frame(seq: int) -> bytes:
    rng = np.random.default_rng(seq)
    left = rng.integers(0, 255, (24, 32), dtype=np.uint8)
    intr = StereoIntrinsics(32, 24, 30.0, 30.0, 16.0, 12.0, 0.2)
    return stereo_frame.encode(
        stereo_frame.StereoFrame(seq, 1_000_000 * seq, intr, left, left.copy())
    )


def _session(conf: zenoh.Config, endpoint: str) -> zenoh.Session:
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("connect/timeout_ms", json.dumps({"peer": 2000}))
    conf.insert_json5("connect/exit_on_failure", json.dumps({"peer": False}))
    return zenoh.open(conf)


def _plain(endpoint: str, user: str | None = None, password: str | None = None):
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    if user is not None:
        conf.insert_json5("transport/auth/usrpwd", json.dumps({"user": user, "password": password}))
    return _session(conf, endpoint)


def _wait_connected(session: zenoh.Session, timeout_s: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if list(session.info.peers_zid()):
            return True
        time.sleep(0.05)
    return False


def test_only_authenticated_peers_get_frames_accepted(tmp_path):
    # the shipped companion config, with its credentials file where this test keeps it
    creds = tmp_path / "credentials.txt"
    creds.write_text((ZENOH_CONFIGS / "credentials.txt").read_text())
    text = (ZENOH_CONFIGS / "companion.json5").read_text()
    assert "/config/zenoh/credentials.txt" in text
    companion_conf = tmp_path / "companion.json5"
    companion_conf.write_text(text.replace("/config/zenoh/credentials.txt", str(creds)))
    endpoint = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    companion = ChildProcess(
        "companion",
        "companion",
        [
            "--mavlink",
            f"udpout:127.0.0.1:{free_port()}",
            "--zenoh-config",
            str(companion_conf),
            "--zenoh-listen",
            endpoint,
            "--vehicle-id",
            "auth1",
        ],
    )
    sessions = []
    try:
        companion.wait_line(r"^COMPANION READY ", 60)
        key = stereo_key("auth1")
        intruders = [
            _plain(endpoint),  # no credentials
            _plain(endpoint, "plant-sim", "guessed"),  # a wrong password
            _plain(endpoint, "mallory", "change-me-plant-sim"),  # not in the dictionary
        ]
        sessions += intruders
        for s in intruders:
            for seq in range(N_FRAMES):
                s.put(key, _frame(seq))
        # the shipped publisher config: authenticated as plant-sim
        good = _session(zenoh.Config.from_file(str(ZENOH_CONFIGS / "publisher.json5")), endpoint)
        sessions.append(good)
        assert _wait_connected(good), companion.logs()
        time.sleep(0.5)  # the subscriber's declaration reaches the new peer
        for seq in range(N_FRAMES):
            good.put(key, _frame(100 + seq))
        time.sleep(1.0)  # loopback delivery takes milliseconds; STATS below counts exactly
    finally:
        for s in sessions:
            s.close()
        companion.stop()
        print(companion.logs())
        companion.close()
    stats = companion.stats("COMPANION STATS ")
    assert stats is not None, companion.logs()
    assert stats["frames_received"] == N_FRAMES, stats
    assert stats["frames_malformed"] == 0
