"""Test helpers: run ``python -m plant_sim`` on loopback and talk MAVLink to it."""

from __future__ import annotations

import contextlib
import re
import time

from pymavlink import mavutil

from evaluation.sil import ChildProcess, free_port

__all__ = ["READY_RE", "PlantProcess", "command", "connect", "free_port", "recv"]

READY_RE = re.compile(r"^PLANT_SIM READY mavlink=(\S+) zenoh=(\S+) key=(\S+) speedup=(\S+)")


class PlantProcess(ChildProcess):
    """A ``python -m plant_sim`` child (see :class:`evaluation.sil.ChildProcess`)
    that knows its readiness line, its STATS line and its MAVLink port."""

    def __init__(self, args: list[str], env: dict | None = None) -> None:
        super().__init__("plant-sim", "plant_sim", args, env)
        self.ready: re.Match | None = None
        self.mavlink_port: int | None = None
        self.clients: list = []  # pymavlink connections closed by close()

    def wait_ready(self, timeout_s: float = 180.0) -> re.Match:
        # seconds on an idle machine; over 60 s at load 24 on two cores with numba's kernels
        # to compile (a fresh checkout). The wait ends at the line.
        m = self.wait_line(READY_RE.pattern, timeout_s)
        self.ready = m
        port = re.search(r"udpin:[^,]*:(\d+)", m.group(1))
        self.mavlink_port = int(port.group(1)) if port else None
        return m

    def stop(self, timeout_s: float = 15.0) -> dict | None:
        """SIGTERM, wait, return the parsed STATS line (None if absent)."""
        super().stop(timeout_s)
        return self.stats("PLANT_SIM STATS ")

    def client(self, **kw):
        """An unconnected pymavlink client to this plant's udpin port, closed by close()."""
        m = mavutil.mavlink_connection(f"udpout:127.0.0.1:{self.mavlink_port}", **kw)
        self.clients.append(m)
        return m

    def close(self) -> None:
        for m in self.clients:
            with contextlib.suppress(OSError):
                m.close()
        super().close()


def connect(plant: PlantProcess, *, key: bytes | None = None, sysid: int = 255, compid: int = 190):
    """pymavlink client to the plant; says hello and waits for a heartbeat."""
    m = plant.client(source_system=sysid, source_component=compid, dialect="ardupilotmega")
    if key is not None:
        m.setup_signing(key, sign_outgoing=True)
    # seconds on an idle machine; over 10 s once at load 27 on two cores (the wait ends at
    # the first heartbeat)
    deadline = time.monotonic() + 60.0
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
