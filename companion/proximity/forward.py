"""Datagrams the OBSTACLE_DISTANCE process read, forwarded in order to the main loop.

The process (:mod:`companion.proximity.process`) is the only reader of the companion's
UDP socket while it runs: it takes each datagram as it arrives (so its pose never waits
for a busy main loop), and hands every one, bytes unchanged, with the address it came
from, to the main loop through a local stream socket (``AF_UNIX``, ``SOCK_STREAM``: one
ordered byte stream, no per-datagram queue limit; a ``SOCK_DGRAM`` pair queues at most
``net.unix.max_dgram_qlen`` = 10 datagrams on this kernel). Each datagram is one record:

    IPv4 address (4 bytes) | port (u16 LE) | length (u16 LE) | the datagram

The process never blocks on the main loop: what the socket's buffer (``BUFFER_BYTES``)
cannot take now waits in the process (:class:`ForwardQueue`), up to ``PENDING_BYTES``
(at 200 datagrams/s of 60–300 bytes, minutes of a stalled main loop); beyond that whole
datagrams are dropped and counted, never cut. The main loop reads the stream with
:class:`ForwardReader` and parses the datagrams exactly as if it had read them itself
(:meth:`companion.link.connection.MavlinkConnection.poll`).
"""

from __future__ import annotations

import socket
import struct
from collections import deque

__all__ = [
    "BUFFER_BYTES",
    "PENDING_BYTES",
    "ForwardQueue",
    "ForwardReader",
    "encode_record",
    "forward_pair",
]

#: The stream socket's send and receive buffers [bytes] (the kernel caps them at
#: ``net.core.wmem_max`` / ``rmem_max``).
BUFFER_BYTES = 1 << 21
#: Bytes the process keeps when the stream is full, before it drops datagrams.
PENDING_BYTES = 1 << 23
_HEADER = struct.Struct("<4sHH")
_READ_BYTES = 1 << 18  # one read of the stream


def forward_pair() -> tuple[socket.socket, socket.socket]:
    """(main loop's end, process's end): a non-blocking local stream pair with large
    buffers; create it before the fork."""
    ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
    for sock in (ours, theirs):
        for opt in (socket.SO_SNDBUF, socket.SO_RCVBUF):
            sock.setsockopt(socket.SOL_SOCKET, opt, BUFFER_BYTES)
        sock.setblocking(False)
    return ours, theirs


def encode_record(addr: tuple[str, int], data: bytes) -> bytes | None:
    """The record of ``data`` from ``addr``; None when it has no record (not IPv4, or
    longer than 65535 bytes: a UDP socket of the companion delivers neither)."""
    try:
        ip = socket.inet_aton(addr[0])
    except (OSError, TypeError, IndexError):
        return None
    if len(data) > 0xFFFF or not 0 <= int(addr[1]) <= 0xFFFF:
        return None
    return _HEADER.pack(ip, int(addr[1]), len(data)) + data


class ForwardQueue:
    """The process's side: records not yet taken by the stream socket, oldest first.

    Parameters
    ----------
    limit_bytes : int
        Bytes kept before whole datagrams are dropped (counted in :attr:`dropped`).
    """

    def __init__(self, limit_bytes: int = PENDING_BYTES) -> None:
        self._limit = limit_bytes
        self._records: deque[memoryview] = deque()
        self._bytes = 0
        self.forwarded = 0  # records wholly written
        self.dropped = 0  # datagrams not forwarded: the queue was full, or no record

    def __len__(self) -> int:
        return len(self._records)

    def push(self, addr: tuple[str, int], data: bytes) -> None:
        record = encode_record(addr, data)
        if record is None or self._bytes + len(record) > self._limit:
            self.dropped += 1
            return
        self._records.append(memoryview(record))
        self._bytes += len(record)

    def flush(self, sock: socket.socket) -> None:
        """Write what the non-blocking ``sock`` takes now, in order (a record cut by a
        full buffer is finished first next time). Raises OSError when the main loop's end
        is gone (the caller stops forwarding)."""
        records = self._records
        while records:
            head = records[0]
            try:
                n = sock.send(head)
            except BlockingIOError:
                return
            self._bytes -= n
            if n == len(head):
                records.popleft()
                self.forwarded += 1
            else:
                records[0] = head[n:]
                return


class ForwardReader:
    """The main loop's side: the datagrams in the stream, in the order they were read."""

    def __init__(self, sock: socket.socket) -> None:
        self._sock = sock
        self._buf = bytearray()
        self.closed = False  # the process's end is closed (it ended)

    def fileno(self) -> int:
        return self._sock.fileno()

    def take(self, max_bytes: int = 1 << 24) -> list[tuple[tuple[str, int], bytes]]:
        """Every whole datagram waiting (reads up to ``max_bytes``), oldest first."""
        read = 0
        while read < max_bytes and not self.closed:
            try:
                chunk = self._sock.recv(_READ_BYTES)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                self.closed = True
                break
            if not chunk:
                self.closed = True
                break
            self._buf += chunk
            read += len(chunk)
        return self._records()

    def _records(self) -> list[tuple[tuple[str, int], bytes]]:
        out = []
        buf, pos = self._buf, 0
        while len(buf) - pos >= _HEADER.size:
            ip, port, length = _HEADER.unpack_from(buf, pos)
            end = pos + _HEADER.size + length
            if end > len(buf):
                break
            out.append(((socket.inet_ntoa(ip), port), bytes(buf[pos + _HEADER.size : end])))
            pos = end
        del buf[:pos]
        return out

    def close(self) -> None:
        self._sock.close()
        self.closed = True
