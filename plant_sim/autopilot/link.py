"""MAVLink 2 over UDP: several endpoints, robust framing, signing checked before replay state.

Endpoints use pymavlink-style URLs:

* ``udpin:HOST:PORT`` (or ``udp:``) — bind and answer every peer that writes to it
  (peers silent for ``PEER_TIMEOUT_S`` of wall time are forgotten);
* ``udpout:HOST:PORT`` — send to that address from an ephemeral port and read its replies.

Each datagram is framed on its own (no state carried across datagrams or senders): garbage,
truncated frames, bad CRCs, unknown message ids and refused signatures are counted in
:class:`LinkStats` and dropped, never raised. With a signing key, every incoming frame must
carry a valid signature: the SHA-256 signature is verified *before* the per-stream
timestamp is consulted or updated, so a forged frame with a huge timestamp cannot block a
genuine stream (pymavlink's own ``check_signature`` updates the timestamp first). Outgoing
frames are signed with the same key. Keys never reach logs: :class:`SigningKey` has no key
in its ``repr``.

Replay protection survives a restart, as the MAVLink signing spec asks: the newest accepted
timestamp of every stream is saved to a state file (atomically, at most once a second and
at close) and loaded at start, so a signed frame captured before the restart is refused
instead of being accepted once as a "new stream" within its one-minute window.

Routing, as ArduPilot does it: a frame that is broadcast (no target, or target system 0) or
addressed to another system/component is forwarded unchanged to the other peers (so a
ground station sees the companion's heartbeat and a second companion on the same ids is
seen by the first). Frames addressed to this autopilot are never forwarded; each source
has a forwarding budget.
"""

from __future__ import annotations

import dataclasses
import errno
import json
import logging
import os
import select
import socket
import struct
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from plant_sim.autopilot.ratelimit import TokenBucket
from protocols.signing import SignatureVerifier, SigningKey, signing_timestamp_now

__all__ = [
    "PEER_TIMEOUT_S",
    "EndpointSpec",
    "LinkStats",
    "MavlinkLink",
    "load_signing_state",
    "parse_endpoint",
    "save_signing_state",
    "split_frames",
]

_log = logging.getLogger("plant_sim.link")

PEER_TIMEOUT_S = 30.0
_MAX_DATAGRAM = 65535
_V1, _V2 = 0xFE, 0xFD
_IFLAG_SIGNED = 0x01


@dataclass(frozen=True)
class EndpointSpec:
    """A parsed endpoint URL."""

    kind: str  # "udpin" | "udpout"
    host: str
    port: int

    @property
    def url(self) -> str:
        return f"{self.kind}:{self.host}:{self.port}"


def parse_endpoint(url: str) -> EndpointSpec:
    """Parse ``udpin:HOST:PORT``, ``udp:HOST:PORT`` or ``udpout:HOST:PORT``.

    Raises
    ------
    ValueError
        With the URL and what is wrong.
    """
    parts = url.split(":")
    if len(parts) != 3:
        raise ValueError(
            f"MAVLink endpoint {url!r}: expected KIND:HOST:PORT (e.g. udpin:0.0.0.0:14550)"
        )
    kind, host, port_text = parts
    kind = {"udp": "udpin"}.get(kind, kind)
    if kind not in ("udpin", "udpout"):
        raise ValueError(f"MAVLink endpoint {url!r}: kind must be udpin, udp or udpout")
    try:
        port = int(port_text)
    except ValueError:
        raise ValueError(f"MAVLink endpoint {url!r}: port {port_text!r} is not a number") from None
    if not (0 <= port <= 65535) or (kind == "udpout" and port == 0):
        raise ValueError(f"MAVLink endpoint {url!r}: port {port} out of range")
    if not host:
        raise ValueError(f"MAVLink endpoint {url!r}: empty host")
    return EndpointSpec(kind, host, port)


@dataclass
class LinkStats:
    """Counters of everything received; ``dropped`` sums every refusal."""

    datagrams: int = 0
    frames_ok: int = 0
    garbage_bytes: int = 0
    truncated: int = 0
    bad_frames: int = 0  # CRC, header or payload errors
    unknown_msgid: int = 0
    unsigned_refused: int = 0
    bad_signature_refused: int = 0
    replay_refused: int = 0
    foreign_target: int = 0  # valid frames addressed to another system/component
    socket_errors: int = 0
    forwarded: int = 0  # frames routed to the other peers
    forward_limited: int = 0  # frames not routed: the source's budget was spent

    @property
    def signing_refused(self) -> int:
        return self.unsigned_refused + self.bad_signature_refused + self.replay_refused

    @property
    def dropped(self) -> int:
        return self.truncated + self.bad_frames + self.unknown_msgid + self.signing_refused

    def as_dict(self) -> dict[str, int]:
        return dataclasses.asdict(self)


def split_frames(data: bytes) -> Iterator[tuple[str, int, bytes]]:
    """Cut a datagram into candidate MAVLink frames.

    Yields ``("frame", offset, bytes)`` for each length-consistent candidate,
    ``("garbage", offset, bytes)`` for bytes before a start marker and
    ``("truncated", offset, bytes)`` for a frame that runs past the end. The caller
    validates candidates (CRC, signature); framing resumes after a candidate's length
    whatever its verdict, since UDP senders put whole frames in a datagram.
    """
    i, n = 0, len(data)
    while i < n:
        j = i
        while j < n and data[j] != _V2 and data[j] != _V1:
            j += 1
        if j > i:
            yield ("garbage", i, data[i:j])
        if j >= n:
            return
        if data[j] == _V2:
            if j + 3 > n:
                yield ("truncated", j, data[j:])
                return
            total = 12 + data[j + 1] + (13 if data[j + 2] & _IFLAG_SIGNED else 0)
        else:
            if j + 2 > n:
                yield ("truncated", j, data[j:])
                return
            total = 8 + data[j + 1]
        if j + total > n:
            yield ("truncated", j, data[j:])
            return
        yield ("frame", j, data[j : j + total])
        i = j + total


def load_signing_state(path: Path) -> dict[tuple[int, int, int], int]:
    """Per-stream timestamps saved by :func:`save_signing_state`; {} if there is no file.

    Raises
    ------
    ValueError
        For a file that exists but cannot be read as a signing state (naming the path):
        starting without it would silently reopen the replay window.
    """
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return {}
    try:
        doc = json.loads(text)
        streams = doc["streams"]
        out = {}
        for key, ts in streams.items():
            link_id, sysid, compid = (int(x) for x in key.split(":"))
            if not isinstance(ts, int) or ts < 0:
                raise ValueError(f"bad timestamp {ts!r}")
            out[(link_id, sysid, compid)] = ts
        return out
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        raise ValueError(f"signing state file {path}: unreadable ({exc}); remove it") from None


def save_signing_state(path: Path, last: dict[tuple[int, int, int], int]) -> None:
    """Write the per-stream timestamps atomically (temporary file + rename)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    doc = {"version": 1, "streams": {f"{a}:{b}:{c}": ts for (a, b, c), ts in last.items()}}
    tmp = path.with_name(path.name + f".{os.getpid()}.tmp")
    tmp.write_text(json.dumps(doc), encoding="utf-8")
    os.replace(tmp, path)


@dataclass
class _Endpoint:
    spec: EndpointSpec
    sock: socket.socket
    peers: dict[tuple[str, int], float] = field(default_factory=dict)  # addr → last wall s

    def destinations(self, now_s: float) -> list[tuple[str, int]]:
        if self.spec.kind == "udpout":
            return [(self.spec.host, self.spec.port)]
        stale = [a for a, seen in self.peers.items() if now_s - seen > PEER_TIMEOUT_S]
        for addr in stale:
            del self.peers[addr]
        return list(self.peers)


class MavlinkLink:
    """Sockets of every endpoint, framing, signing and fan-out of outgoing messages.

    Network I/O happens in :meth:`open`, never in ``__init__``. ``on_send`` and
    ``on_receive`` get the raw bytes of every sent / accepted frame (the .tlog).
    """

    def __init__(
        self,
        specs: list[EndpointSpec],
        *,
        system_id: int = 1,
        component_id: int = 1,
        signing_key: SigningKey | None = None,
        on_send: Callable[[bytes], None] | None = None,
        on_receive: Callable[[bytes], None] | None = None,
        log_interval_s: float = 5.0,
        signing_state: Path | None = None,
        forward_rate_per_s: float = 200.0,
    ) -> None:
        if not specs:
            raise ValueError("at least one MAVLink endpoint is needed")
        self._specs = list(specs)
        self._endpoints: list[_Endpoint] = []
        self.system_id = system_id
        self.component_id = component_id
        self.stats = LinkStats()
        self._signing_key = signing_key
        self._verifier: SignatureVerifier | None = None
        self._signing_state = signing_state if signing_key is not None else None
        self._saved_state: dict[tuple[int, int, int], int] = {}
        self._next_state_save_s = 0.0
        self._forward_rate = forward_rate_per_s
        self._forward_buckets: dict[tuple[int, int], TokenBucket] = {}
        self._encoder = mavlink.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        if signing_key is not None:
            self._encoder.signing.secret_key = signing_key.secret
            self._encoder.signing.sign_outgoing = True
            self._encoder.signing.link_id = 0
        self._decoder = mavlink.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        self._on_send = on_send
        self._on_receive = on_receive
        self._log_interval_s = log_interval_s
        self._last_log_s = time.monotonic()
        self._logged = LinkStats()
        self.sent_frames = 0
        self.send_errors = 0

    # ---- lifecycle ----------------------------------------------------------------
    def open(self) -> None:
        """Load the signing state, create and bind the sockets.

        Raises
        ------
        ValueError
            For an unreadable signing state file.
        OSError
            For an endpoint that cannot be bound.
        """
        if self._signing_key is not None:
            last = {}
            if self._signing_state is not None:
                last = load_signing_state(self._signing_state)
                self._saved_state = dict(last)
            self._verifier = SignatureVerifier(self._signing_key, last_timestamps=last)
        for spec in self._specs:
            family = (
                socket.AF_INET6 if ":" in spec.host and spec.host.count(":") > 1 else socket.AF_INET
            )
            sock = socket.socket(family, socket.SOCK_DGRAM)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 * 1024 * 1024)
            if spec.kind == "udpin":
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                try:
                    sock.bind((spec.host, spec.port))
                except OSError as exc:
                    sock.close()
                    raise OSError(
                        exc.errno, f"cannot bind MAVLink endpoint {spec.url}: {exc.strerror}"
                    ) from None
            sock.setblocking(False)
            self._endpoints.append(_Endpoint(spec, sock))

    def close(self) -> None:
        self._save_signing_state(force=True)
        for ep in self._endpoints:
            ep.sock.close()
        self._endpoints.clear()

    def _save_signing_state(self, *, force: bool = False) -> None:
        if self._verifier is None or self._signing_state is None:
            return
        now = time.monotonic()
        if not force and now < self._next_state_save_s:
            return
        self._next_state_save_s = now + 1.0
        last = self._verifier.last_timestamps
        if last == self._saved_state:
            return
        try:
            save_signing_state(self._signing_state, last)
            self._saved_state = last
        except OSError as exc:
            _log.error("cannot save the signing state to %s: %s", self._signing_state, exc)

    @property
    def bound_urls(self) -> list[str]:
        """Endpoint URLs with the actual bound ports (port 0 resolved)."""
        out = []
        for ep in self._endpoints:
            if ep.spec.kind == "udpin":
                _host, port = ep.sock.getsockname()[:2]
                out.append(f"udpin:{ep.spec.host}:{port}")
            else:
                out.append(ep.spec.url)
        return out

    def filenos(self) -> list[socket.socket]:
        return [ep.sock for ep in self._endpoints]

    # ---- sending --------------------------------------------------------------------
    def send(self, msg) -> None:
        """Encode (and sign) ``msg`` once and send it to every endpoint and peer."""
        enc = self._encoder
        if self._signing_key is not None:
            enc.signing.timestamp = max(enc.signing.timestamp, signing_timestamp_now())
        buf = msg.pack(enc)
        enc.seq = (enc.seq + 1) % 256
        self.sent_frames += 1
        if self._on_send is not None:
            self._on_send(buf)
        now = time.monotonic()
        for ep in self._endpoints:
            for addr in ep.destinations(now):
                try:
                    ep.sock.sendto(buf, addr)
                except OSError as exc:
                    # ECONNREFUSED from a closed udpout peer, ENOBUFS under load: count, go on
                    self.send_errors += 1
                    if exc.errno not in (errno.ECONNREFUSED, errno.ENOBUFS, errno.EAGAIN):
                        _log.warning("send to %s failed: %s", addr, exc)

    # ---- receiving ------------------------------------------------------------------
    def wait(self, timeout_s: float) -> bool:
        """Block up to ``timeout_s`` until a socket is readable; True if one is."""
        if not self._endpoints:
            time.sleep(max(0.0, timeout_s))
            return False
        readable, _, _ = select.select(self.filenos(), [], [], max(0.0, timeout_s))
        return bool(readable)

    def poll(self, max_datagrams: int = 2000) -> list:
        """Drain every socket (up to ``max_datagrams``) and return the accepted messages."""
        out: list = []
        now = time.monotonic()
        budget = max_datagrams
        for ep in self._endpoints:
            while budget > 0:
                try:
                    data, addr = ep.sock.recvfrom(_MAX_DATAGRAM)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError as exc:
                    self.stats.socket_errors += 1
                    if exc.errno == errno.ECONNREFUSED:
                        continue  # ICMP port unreachable from a udpout peer that is not up
                    _log.warning("receive on %s failed: %s", ep.spec.url, exc)
                    break
                budget -= 1
                self.stats.datagrams += 1
                accepted = self._handle_datagram(data, out, (ep, addr), now)
                if accepted and ep.spec.kind == "udpin":
                    ep.peers[addr] = now
        self._maybe_log(now)
        self._save_signing_state()
        return out

    def _handle_datagram(self, data: bytes, out: list, origin, now: float) -> bool:
        stats = self.stats
        accepted = False
        for kind, _offset, chunk in split_frames(data):
            if kind == "garbage":
                stats.garbage_bytes += len(chunk)
                continue
            if kind == "truncated":
                stats.truncated += 1
                continue
            msg = self._accept_frame(chunk)
            if msg is not None:
                out.append(msg)
                accepted = True
                if self._should_forward(msg):
                    self._forward(msg, chunk, origin, now)
        return accepted

    def _should_forward(self, msg) -> bool:
        sysid = getattr(msg, "target_system", 0)
        compid = getattr(msg, "target_component", 0)
        if sysid == 0:
            return True
        return sysid != self.system_id or compid not in (0, self.component_id)

    def _forward(self, msg, frame: bytes, origin, now: float) -> None:
        """Send ``frame`` unchanged to every other endpoint and peer, within the budget."""
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        bucket = self._forward_buckets.get(src)
        if bucket is None:
            if len(self._forward_buckets) >= 64:
                self._forward_buckets.clear()
            bucket = TokenBucket(self._forward_rate, 2 * self._forward_rate, now)
            self._forward_buckets[src] = bucket
        if not bucket.take(now):
            self.stats.forward_limited += 1
            return
        origin_ep, origin_addr = origin
        for ep in self._endpoints:
            for addr in ep.destinations(now):
                if ep is origin_ep and addr == origin_addr:
                    continue
                if ep.spec.kind == "udpout" and ep is origin_ep:
                    continue
                try:
                    ep.sock.sendto(frame, addr)
                    self.stats.forwarded += 1
                except OSError:
                    self.send_errors += 1

    def _accept_frame(self, frame: bytes):
        stats = self.stats
        if frame[0] == _V2 and frame[2] & ~_IFLAG_SIGNED:
            stats.bad_frames += 1
            return None
        if self._verifier is not None:
            verdict = self._verifier.verify(frame)
            if verdict is not None:
                # CRC first, so that line noise is not reported as a signing attack
                if not self._crc_ok(frame):
                    stats.bad_frames += 1
                elif verdict == "unsigned":
                    stats.unsigned_refused += 1
                elif verdict == "bad_signature":
                    stats.bad_signature_refused += 1
                else:
                    stats.replay_refused += 1
                return None
        try:
            msg = self._decoder.decode(bytearray(frame))
        except (mavlink.MAVError, struct.error, ValueError, IndexError, TypeError):
            stats.bad_frames += 1
            return None
        if isinstance(msg, mavlink.MAVLink_unknown):
            stats.unknown_msgid += 1
            return None
        if msg.get_srcSystem() == self.system_id and msg.get_srcComponent() == self.component_id:
            stats.foreign_target += 1  # our own frames looped back
            return None
        stats.frames_ok += 1
        if self._on_receive is not None:
            self._on_receive(frame)
        return msg

    def _crc_ok(self, frame: bytes) -> bool:
        try:
            self._decoder.decode(bytearray(frame))
        except (mavlink.MAVError, struct.error, ValueError, IndexError, TypeError):
            return False
        return True

    def _maybe_log(self, now: float) -> None:
        if now - self._last_log_s < self._log_interval_s:
            return
        self._last_log_s = now
        cur, prev = self.stats.as_dict(), self._logged.as_dict()
        delta = {
            k: cur[k] - prev[k]
            for k in cur
            if cur[k] != prev[k] and k not in ("datagrams", "frames_ok", "forwarded")
        }
        if delta:
            _log.warning(
                "MAVLink input dropped in the last %.0f s: %s", self._log_interval_s, delta
            )
        self._logged = dataclasses.replace(self.stats)
