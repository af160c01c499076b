"""The MAVLink 2 signing key both processes share (DESIGN.md "MAVLink 2 signing")."""

from __future__ import annotations

import hashlib
import hmac
import struct
import time
from collections.abc import Callable

__all__ = [
    "SIGNING_KEY_ENV",
    "SignatureVerifier",
    "SigningKey",
    "signature_valid",
    "signing_timestamp_now",
]

_IFLAG_SIGNED = 0x01
_V2 = 0xFD
_SIGNING_EPOCH_UNIX_S = 1420070400  # 2015-01-01T00:00:00Z, MAVLink signing epoch
_NEW_STREAM_WINDOW = 60 * 100_000  # a new stream may lag our timestamp by 1 min [10 µs]

#: Environment variable either process reads the key from (keeps it off command lines).
SIGNING_KEY_ENV = "STEREO_AVOID_SIGNING_KEY"


class SigningKey:
    """A 32-byte MAVLink 2 signing key: 64 hex digits, or a passphrase hashed with SHA-256.

    Its ``repr`` never shows the secret, so the key cannot leak into logs by accident.
    """

    __slots__ = ("_secret",)

    def __init__(self, secret: bytes) -> None:
        if len(secret) != 32:
            raise ValueError(f"a signing key has 32 bytes, got {len(secret)}")
        self._secret = bytes(secret)

    @classmethod
    def from_text(cls, text: str) -> SigningKey:
        """64 hex digits → those bytes; anything else → SHA-256 of the UTF-8 passphrase.

        Raises
        ------
        ValueError
            For an empty key.
        """
        text = text.strip()
        if not text:
            raise ValueError("empty signing key")
        if len(text) == 64:
            try:
                return cls(bytes.fromhex(text))
            except ValueError:
                pass
        return cls(hashlib.sha256(text.encode("utf-8")).digest())

    @property
    def secret(self) -> bytes:
        """The 32 key bytes (hand them to pymavlink, never to a logger)."""
        return self._secret

    def __repr__(self) -> str:
        return "SigningKey(<redacted>)"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, SigningKey) and other._secret == self._secret

    def __hash__(self) -> int:
        return hash(self._secret)


def signature_valid(secret: bytes, frame: bytes | bytearray) -> bool:
    """True if ``frame`` (one whole MAVLink 2 frame) carries a valid signature for ``secret``.

    The signature is the first 6 bytes of SHA-256(secret + frame without those 6 bytes);
    compared in constant time. Checked before any replay state is touched (both processes).
    """
    if len(frame) < 25 or frame[0] != 0xFD or not frame[2] & _IFLAG_SIGNED:
        return False
    expected = hashlib.sha256(bytes(secret) + bytes(frame[:-6])).digest()[:6]
    return hmac.compare_digest(expected, bytes(frame[-6:]))


def signing_timestamp_now(wall_unix_s: float | None = None) -> int:
    """MAVLink signing timestamp [10 µs since 2015-01-01] for the wall clock."""
    now = time.time() if wall_unix_s is None else wall_unix_s
    return int((now - _SIGNING_EPOCH_UNIX_S) * 100_000)


class SignatureVerifier:
    """MAVLink 2 signature check with replay protection, in the safe order.

    1. signature (SHA-256 over key + frame without the signature) — a forgery stops here and
       touches no state;
    2. timestamp against the stream's last one (new streams: within one minute of ours);
    3. only then record the timestamp.
    """

    def __init__(
        self,
        key: SigningKey,
        clock_unix_s: Callable[[], float] = time.time,
        last_timestamps: dict[tuple[int, int, int], int] | None = None,
    ) -> None:
        self._key = key
        self._clock = clock_unix_s
        self._last: dict[tuple[int, int, int], int] = dict(last_timestamps or {})

    @property
    def last_timestamps(self) -> dict[tuple[int, int, int], int]:
        """Newest accepted timestamp per (link id, system, component) stream."""
        return dict(self._last)

    def verify(self, frame: bytes) -> str | None:
        """None if ``frame`` is acceptable, else "unsigned" / "bad_signature" / "replay"."""
        if frame[0] != _V2 or not frame[2] & _IFLAG_SIGNED or len(frame) < 25:
            return "unsigned"
        if not signature_valid(self._key.secret, frame):
            return "bad_signature"
        link_id = frame[-13]
        tlow, thigh = struct.unpack_from("<IH", frame, len(frame) - 12)
        timestamp = tlow | (thigh << 32)
        stream = (link_id, frame[5], frame[6])
        last = self._last.get(stream)
        if last is not None:
            if timestamp <= last:
                return "replay"
        elif timestamp + _NEW_STREAM_WINDOW < signing_timestamp_now(self._clock()):
            return "replay"
        self._last[stream] = timestamp
        return None
