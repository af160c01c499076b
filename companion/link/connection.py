"""The MAVLink connection: pymavlink transport, signing in the safe order, counted drops.

:class:`MavlinkConnection` wraps ``pymavlink.mavutil.mavlink_connection`` (so every URL
pymavlink knows works: ``udpin:``, ``udpout:``, ``tcp:``, ``tcpin:``, serial devices) and
adds what the companion needs around it:

* MAVLink 2 signing with a 32-byte key. pymavlink's ``check_signature`` records a new
  stream's timestamp *before* it verifies the signature, so one forged frame with a huge
  timestamp would block the genuine stream; here it is replaced by
  :class:`protocols.signing.SignatureVerifier` (the check plant-sim uses too): the SHA-256
  signature first, and the replay check only for authentic frames.
* Counters of every refused or malformed frame (:class:`LinkCounters`), never an exception.
* ``poll()`` drains everything that is waiting (a receiver that falls behind a 50 Hz ×
  speedup stream must drain, DESIGN.md budget), ``fileno()`` for ``select``.
* A forwarder (:meth:`MavlinkConnection.forward_from`): another reader of a UDP socket
  (the OBSTACLE_DISTANCE process) hands over each datagram with its source, and ``poll()``
  parses them exactly as if it had read them itself (the same parser, signing check and
  peer bookkeeping), then reads the socket itself whenever the forwarder says so.
* A shared sequence number (:attr:`MavlinkConnection.seq_source`) for two senders of one
  component.

Network I/O happens in :meth:`open`, never in ``__init__``. The key never reaches a log.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import socket
import struct
import time
import types
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.config import SigningKey
from protocols.signing import SignatureVerifier

__all__ = ["Forwarder", "LinkCounters", "MavlinkConnection"]

_log = logging.getLogger("companion.link")
_RCVBUF_BYTES = 1 << 20  # the UDP socket's receive buffer [bytes]


@dataclass
class LinkCounters:
    """What arrived and what was refused."""

    messages: int = 0
    bad_data: int = 0  # CRC / framing errors
    signing_refused: int = 0  # unsigned, bad signature or replayed
    send_errors: int = 0
    sent: int = 0

    def as_dict(self) -> dict[str, int]:
        return dataclasses.asdict(self)


class Forwarder(Protocol):
    """Another reader of the link's UDP socket
    (:class:`~companion.proximity.process.ProximityProcess`)."""

    def forwarded(self) -> list[tuple[tuple[str, int], bytes]]:
        """Datagrams read since the last call, with their sources, oldest first."""

    def main_reads(self) -> bool:
        """True while this connection must read the socket itself."""


def _verified_by(verifier: SignatureVerifier):
    """pymavlink's ``check_signature`` replaced by ``verifier`` (signature, then replay);
    our outgoing timestamp stays ahead of every accepted one, as pymavlink keeps it."""

    def check(self, msgbuf, src_system, src_component):
        if verifier.verify(bytes(msgbuf)) is not None:
            return False
        tlow, thigh = struct.unpack_from("<IH", msgbuf, len(msgbuf) - 12)
        self.signing.timestamp = max(self.signing.timestamp, tlow | (thigh << 32))
        return True

    return check


class MavlinkConnection:
    """One pymavlink connection to the autopilot.

    Parameters
    ----------
    url : str
        pymavlink connection string.
    system_id, component_id : int
        Our identity (component 196 = MAV_COMP_ID_OBSTACLE_AVOIDANCE by default).
    signing_key : SigningKey or None
        With a key: outgoing frames are signed, unsigned or badly signed input is refused.
    signing_link_id : int
        The link id our signatures carry (0–255). Two connections with the same system and
        component ids (the OBSTACLE_DISTANCE process beside the main loop) need two: the
        receiver keeps the newest timestamp per (system, component, link).
    """

    def __init__(
        self,
        url: str,
        *,
        system_id: int = 1,
        component_id: int = 196,
        baud: int = 921600,
        signing_key: SigningKey | None = None,
        signing_link_id: int = 0,
    ) -> None:
        self.url = url
        self.signing_link_id = signing_link_id
        self.system_id = system_id
        self.component_id = component_id
        self.baud = baud
        self._signing_key = signing_key
        self._conn = None
        self._resolved: tuple[str, str] | None = None  # udpout: (host, its IPv4 address)
        self.counters = LinkCounters()
        self._forwarder: Forwarder | None = None
        self._inbox: deque[tuple[tuple[str, int], bytes]] = deque()
        self._reads_socket = True
        #: Where the sequence number of each frame sent comes from (None: pymavlink's own)
        self.seq_source: Callable[[], int] | None = None

    @property
    def signing(self) -> bool:
        return self._signing_key is not None

    def open(self) -> None:
        """Open the transport (bind / connect). Raises OSError with the URL on failure."""
        # MAVLink 2 from the first byte: otherwise mavutil starts with MAVLink 1 and, on the
        # first MAVLink 2 frame it receives, replaces its encoder, losing the signing setup.
        os.environ["MAVLINK20"] = "1"
        try:
            conn = mavutil.mavlink_connection(
                self.url,
                baud=self.baud,
                source_system=self.system_id,
                source_component=self.component_id,
                dialect="ardupilotmega",
                autoreconnect=True,
            )
        except (OSError, ValueError) as exc:
            raise OSError(f"cannot open MAVLink connection {self.url!r}: {exc}") from None
        conn.mav.robust_parsing = True
        if isinstance(conn, mavutil.mavudp):
            # room for a burst while the reader is off the processor (a loaded machine, the
            # OBSTACLE_DISTANCE process descheduled): the kernel caps it at rmem_max
            with contextlib.suppress(OSError):
                conn.port.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, _RCVBUF_BYTES)
        if self._signing_key is not None:
            conn.setup_signing(
                self._signing_key.secret,
                sign_outgoing=True,
                allow_unsigned_callback=None,
                link_id=self.signing_link_id,
            )
            verifier = SignatureVerifier(self._signing_key)
            conn.mav.check_signature = types.MethodType(_verified_by(verifier), conn.mav)
        self._conn = conn

    def close(self) -> None:
        if self._conn is not None:
            try:
                self._conn.close()
            except OSError as exc:
                _log.debug("closing MAVLink connection: %s", exc)
            self._conn = None

    def fileno(self) -> int | None:
        """File descriptor to ``select`` on, or None (then poll periodically)."""
        if self._conn is None:
            return None
        fd = getattr(self._conn, "fd", None)
        if isinstance(fd, int) and fd >= 0:
            return fd
        port = getattr(self._conn, "port", None)
        if port is not None and hasattr(port, "fileno"):
            try:
                return port.fileno()
            except (OSError, ValueError):
                return None
        return None

    def udp_peers(self) -> list[tuple[str, int]] | None:
        """The addresses this link's UDP socket sends to: ``udpout``'s destination, or the
        peers a ``udpin`` / ``udp`` socket has heard from (pymavlink writes to each); None
        for other transports (serial, TCP, broadcast). A second writer on the same socket
        (:mod:`companion.proximity.process`) sends to the same peers from the same port."""
        conn = self._conn
        if not isinstance(conn, mavutil.mavudp) or conn.broadcast:
            return None
        if conn.udp_server:
            return sorted(conn.clients)
        host, port = conn.destination_addr
        if self._resolved is None or self._resolved[0] != host:
            try:
                self._resolved = (host, socket.gethostbyname(host))
            except OSError as exc:
                _log.debug("cannot resolve %s: %s", host, exc)
                return []
        return [(self._resolved[1], int(port))]

    def forward_from(self, forwarder: Forwarder | None) -> None:
        """Take the datagrams ``forwarder`` read from this UDP link's socket (None: read the
        socket again, alone). ``poll()`` parses them in order, as pymavlink's own UDP reader
        would (a ``udpin`` socket learns its peers from them), before anything it reads
        from the socket itself, which it does only while ``forwarder.main_reads()``."""
        conn = self._conn
        if not isinstance(conn, mavutil.mavudp):
            raise ValueError(f"only a UDP link's datagrams can be forwarded, not {self.url!r}")
        self._forwarder = forwarder
        if forwarder is None:
            conn.__dict__.pop("recv", None)  # pymavlink's own reader again
            self._reads_socket = True
            return
        own_recv = type(conn).recv.__get__(conn)
        inbox = self._inbox

        def recv(n=None):
            if inbox:
                addr, data = inbox.popleft()
                if conn.udp_server:
                    conn.clients.add(addr)
                    conn.clients_last_alive[addr] = time.time()
                elif conn.broadcast:
                    conn.last_address = addr
                return data
            return own_recv(n) if self._reads_socket else ""

        conn.recv = recv

    @property
    def forwarded(self) -> bool:
        """Whether another process reads the socket now (select on the forwarder, not on
        :meth:`fileno`)."""
        return self._forwarder is not None and not self._reads_socket

    @property
    def signing_timestamp(self) -> int:
        """The timestamp our next signed frame carries [10 µs since 2015-01-01]; 0 without
        a key. It stays ahead of every authentic frame received (:func:`_verified_by`)."""
        if self._conn is None or self._signing_key is None:
            return 0
        return int(self._conn.mav.signing.timestamp)

    def poll(self, max_messages: int = 5000) -> list:
        """Every message waiting (up to ``max_messages``); bad frames are counted."""
        out: list = []
        conn = self._conn
        if conn is None:
            return out
        c = self.counters
        forwarder = self._forwarder
        if forwarder is not None:
            self._inbox.extend(forwarder.forwarded())
            self._reads_socket = forwarder.main_reads()
        for _ in range(max_messages):
            try:
                msg = conn.recv_msg()
            except (OSError, mavlink.MAVError, ValueError, IndexError) as exc:
                c.bad_data += 1
                _log.debug("MAVLink receive error: %s", exc)
                break
            if msg is None:
                if self._inbox:  # a forwarded datagram with no whole frame: the next
                    continue
                break
            mtype = msg.get_type()
            if mtype == "BAD_DATA":
                reason = str(getattr(msg, "reason", ""))
                if "signature" in reason.lower():
                    c.signing_refused += 1
                else:
                    c.bad_data += 1
                continue
            if (
                msg.get_srcSystem() == self.system_id
                and msg.get_srcComponent() == self.component_id
                and mtype != "HEARTBEAT"
            ):
                continue  # our own frames echoed back (heartbeats: see companion.takeover)
            c.messages += 1
            out.append(msg)
        return out

    def send(self, msg) -> bool:
        """Encode, sign (with a key) and send; False (counted) if the transport failed."""
        if self._conn is None:
            return False
        try:
            if self.seq_source is not None:
                self._conn.mav.seq = self.seq_source()
            self._conn.mav.send(msg)
        except (OSError, mavlink.MAVError) as exc:
            self.counters.send_errors += 1
            _log.debug("MAVLink send failed: %s", exc)
            return False
        self.counters.sent += 1
        return True
