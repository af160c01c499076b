"""Hostile MAVLink for the fuzz tests: every field of a message type from a seeded generator.

Each message gets, field by field, either a plausible value or a hostile one: NaN, ±inf,
±1e30, negative numbers, integer extremes, out-of-enum values, random bytes in strings and
wrong targets. Targets are right most of the time, so the handlers behind the address check
are the ones exercised.
"""

from __future__ import annotations

import itertools
import math
import random
import struct

from pymavlink.dialects.v20 import ardupilotmega as mavlink

__all__ = ["HostileMavlink"]

_INT_RANGES = {
    "uint8_t": (0, 2**8 - 1),
    "uint16_t": (0, 2**16 - 1),
    "uint32_t": (0, 2**32 - 1),
    "uint64_t": (0, 2**64 - 1),
    "int8_t": (-(2**7), 2**7 - 1),
    "int16_t": (-(2**15), 2**15 - 1),
    "int32_t": (-(2**31), 2**31 - 1),
    "int64_t": (-(2**63), 2**63 - 1),
}
_HOSTILE_FLOATS = (math.nan, math.inf, -math.inf, 1e30, -1e30, -1.0, -1e6, 3.4e38)


class HostileMavlink:
    """Seeded hostile messages of the given types, packed as MAVLink 2 frames.

    Parameters
    ----------
    types : message class names without the ``MAVLink_`` prefix / ``_message`` suffix,
        e.g. ``"command_long"``.
    target : the (system, component) the receiver answers to.
    commands : MAV_CMD values to draw from for COMMAND_LONG/INT (most of the time).
    sources : (system, component) identities to send from.
    """

    def __init__(self, types, *, target, seed, commands=(), sources=((255, 190),)) -> None:
        self.rng = random.Random(seed)
        self.classes = [getattr(mavlink, f"MAVLink_{t}_message") for t in types]
        self.target = target
        self.commands = tuple(commands)
        self.encoders = {
            s: mavlink.MAVLink(None, srcSystem=s[0], srcComponent=s[1]) for s in sources
        }
        self.sources = tuple(sources)

    def _number(self, ftype: str, plausible):
        rng = self.rng
        if rng.random() < 0.5:
            return plausible()
        if ftype in ("float", "double"):
            return rng.choice(_HOSTILE_FLOATS)
        lo, hi = _INT_RANGES[ftype]
        return rng.choice((lo, hi, 0, 1, hi // 2 + 1, rng.randint(lo, hi)))

    def _field(self, cls, name: str, ftype: str, length: int):
        rng = self.rng
        if name == "target_system":
            return rng.choice((self.target[0],) * 8 + (0, rng.randint(0, 255)))
        if name == "target_component":
            return rng.choice((self.target[1],) * 7 + (0, 0, rng.randint(0, 255)))
        if name == "command" and self.commands and rng.random() < 0.9:
            return rng.choice(self.commands)
        if ftype == "char":
            n = rng.randint(0, length)
            if rng.random() < 0.5:
                return bytes(rng.randrange(256) for _ in range(n))
            return bytes(rng.choice(b"ABCDEFGHIJKLMNOPQRSTUVWXYZ_0123456789") for _ in range(n))
        if ftype in ("float", "double"):
            plausible = lambda: rng.choice((0.0, 1.0, rng.uniform(-100.0, 100.0)))  # noqa: E731
        else:
            lo, hi = _INT_RANGES[ftype]
            plausible = lambda: rng.randint(max(lo, 0), min(hi, 20))  # noqa: E731
        if length:
            return [self._number(ftype, plausible) for _ in range(length)]
        return self._number(ftype, plausible)

    def message(self):
        """One hostile message object and the (system, component) to send it from."""
        cls = self.rng.choice(self.classes)
        values = []
        for name, ftype, length in zip(
            cls.fieldnames, cls.fieldtypes, cls.array_lengths, strict=True
        ):
            values.append(self._field(cls, name, ftype, length))
        return cls(*values), self.rng.choice(self.sources)

    def frames(self, n: int):
        """``n`` packed frames (messages that cannot be packed are redrawn)."""
        out = []
        while len(out) < n:
            msg, src = self.message()
            try:
                out.append(bytes(msg.pack(self.encoders[src])))
            except (struct.error, OverflowError, ValueError, TypeError):
                continue
        return out


def flood_and_watch_heartbeats(port: int, frame: bytes, rate_hz: float, duration_s: float):
    """Send ``frame`` to 127.0.0.1:``port`` at ``rate_hz`` for ``duration_s`` while another
    client watches the autopilot's heartbeats; returns (sent, largest heartbeat gap [s]).

    The watcher is a plain socket that says hello once a second (as a ground station does)
    and timestamps every HEARTBEAT from system 1, component 1.
    """
    import socket
    import threading
    import time

    hello = mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3).pack(
        mavlink.MAVLink(None, srcSystem=254, srcComponent=190)
    )
    stamps: list[float] = []
    stop = threading.Event()

    def watch() -> None:
        parser = mavlink.MAVLink(None)
        parser.robust_parsing = True
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.settimeout(0.05)
            next_hello = 0.0
            while not stop.is_set():
                now = time.monotonic()
                if now >= next_hello:
                    s.sendto(hello, ("127.0.0.1", port))
                    next_hello = now + 1.0
                try:
                    data = s.recv(65535)
                except TimeoutError:
                    continue
                for msg in parser.parse_buffer(data) or []:
                    if msg.get_type() == "HEARTBEAT" and msg.get_srcComponent() == 1:
                        stamps.append(time.monotonic())

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    deadline = time.monotonic() + 5.0
    while not stamps and time.monotonic() < deadline:
        time.sleep(0.05)
    sent = 0
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        t0 = time.monotonic()
        while (elapsed := time.monotonic() - t0) < duration_s:
            due = int(elapsed * rate_hz) + 1
            while sent < due:
                s.sendto(frame, ("127.0.0.1", port))
                sent += 1
            time.sleep(0.001)
    time.sleep(1.5)  # the heartbeat after the flood closes the last gap
    stop.set()
    watcher.join(2.0)
    window = [t for t in stamps if t >= t0 - 1.0]
    gaps = [b - a for a, b in itertools.pairwise(window)]
    end_gap = (t0 + duration_s) - window[-1] if window else math.inf
    return sent, max([*gaps, end_gap]) if window else math.inf
