"""The MAVLink 2 signing key both processes share (DESIGN.md "MAVLink 2 signing")."""

from __future__ import annotations

import hashlib
import hmac

__all__ = ["SIGNING_KEY_ENV", "SigningKey", "signature_valid"]

_IFLAG_SIGNED = 0x01

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
