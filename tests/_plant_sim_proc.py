"""Test helpers: run ``python -m plant_sim`` on loopback and talk MAVLink to it."""

from __future__ import annotations

import contextlib
import json
import os
import queue
import re
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from pymavlink import mavutil

REPO = Path(__file__).resolve().parents[1]
READY_RE = re.compile(r"^PLANT_SIM READY mavlink=(\S+) zenoh=(\S+) key=(\S+) speedup=(\S+)")


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    """A port the OS reports free on 127.0.0.1 (bind to 0, read it, close)."""
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class PlantProcess:
    """A plant-sim child process with its stdout lines queued and stderr in a file."""

    def __init__(self, args: list[str], env: dict | None = None) -> None:
        self._stderr = tempfile.TemporaryFile(mode="w+")  # noqa: SIM115 (closed in close())
        full_env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", **(env or {})}
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "plant_sim", *args],
            cwd=REPO,
            stdout=subprocess.PIPE,
            stderr=self._stderr,
            text=True,
            env=full_env,
        )
        self.lines: queue.Queue[str] = queue.Queue()
        self.stdout_lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        self.ready: re.Match | None = None
        self.mavlink_port: int | None = None
        self.clients: list = []  # pymavlink connections closed by close()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.stdout_lines.append(line.rstrip("\n"))
            self.lines.put(line.rstrip("\n"))

    def wait_ready(self, timeout_s: float = 60.0) -> re.Match:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None and self.lines.empty():
                raise AssertionError(f"plant-sim exited ({self.proc.returncode})\n{self.logs()}")
            try:
                line = self.lines.get(timeout=0.2)
            except queue.Empty:
                continue
            m = READY_RE.match(line)
            if m:
                self.ready = m
                port = re.search(r"udpin:[^,]*:(\d+)", m.group(1))
                self.mavlink_port = int(port.group(1)) if port else None
                return m
        raise AssertionError(f"no readiness line within {timeout_s} s\n{self.logs()}")

    def stop(self, timeout_s: float = 15.0) -> dict | None:
        """SIGTERM, wait, return the parsed STATS line (None if absent)."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=5)
        self._reader.join(timeout=5)
        for line in self.stdout_lines:
            if line.startswith("PLANT_SIM STATS "):
                return json.loads(line[len("PLANT_SIM STATS ") :])
        return None

    def logs(self) -> str:
        self._stderr.seek(0)
        err = self._stderr.read()
        return (
            "--- plant-sim stdout ---\n"
            + "\n".join(self.stdout_lines)
            + ("\n--- plant-sim stderr ---\n" + err[-6000:])
        )

    def client(self, **kw):
        """An unconnected pymavlink client to this plant's udpin port, closed by close()."""
        m = mavutil.mavlink_connection(f"udpout:127.0.0.1:{self.mavlink_port}", **kw)
        self.clients.append(m)
        return m

    def close(self) -> None:
        for m in self.clients:
            with contextlib.suppress(OSError):
                m.close()
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=5)
        self._reader.join(timeout=5)
        if self.proc.stdout is not None:
            self.proc.stdout.close()
        with contextlib.suppress(OSError):
            self._stderr.close()


def connect(plant: PlantProcess, *, key: bytes | None = None, sysid: int = 255, compid: int = 190):
    """pymavlink client to the plant; says hello and waits for a heartbeat."""
    m = plant.client(source_system=sysid, source_component=compid, dialect="ardupilotmega")
    if key is not None:
        m.setup_signing(key, sign_outgoing=True)
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline:
        m.mav.heartbeat_send(
            mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0
        )
        if m.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5) is not None:
            m.target_system, m.target_component = 1, 1
            return m
    raise AssertionError(f"no heartbeat from plant-sim\n{plant.logs()}")


def recv(m, mtype, timeout_s: float = 5.0, cond=None):
    """Next message of type(s) ``mtype`` satisfying ``cond`` within ``timeout_s`` (or None)."""
    deadline = time.monotonic() + timeout_s
    while True:
        left = deadline - time.monotonic()
        if left <= 0:
            return None
        msg = m.recv_match(type=mtype, blocking=True, timeout=left)
        if msg is not None and (cond is None or cond(msg)):
            return msg


def command(m, cmd: int, *params: float, timeout_s: float = 5.0):
    """COMMAND_LONG and its COMMAND_ACK (None if no ACK)."""
    p = [float(x) for x in params] + [0.0] * (7 - len(params))
    m.mav.command_long_send(1, 1, cmd, 0, *p)
    return recv(m, "COMMAND_ACK", timeout_s, cond=lambda a: a.command == cmd)
