"""STATUSTEXT longer than 50 characters: MAVLink 2 chunking (``id``, ``chunk_seq``).

Pure. MAVLink's STATUSTEXT carries 50 characters; MAVLink 2 added ``id`` and ``chunk_seq``
so a longer text goes out as several messages that ground stations (QGroundControl,
MAVProxy, Mission Planner) reassemble: every chunk has the same non-zero ``id``,
``chunk_seq`` counts from 0, and the text ends at the first chunk shorter than 50
characters (a NUL terminates it), so a text whose length is a multiple of 50 gets one more,
empty chunk. A text of at most 50 characters is one message with ``id`` 0 ("only chunk").
"""

from __future__ import annotations

__all__ = ["MAX_CHUNKS", "STATUSTEXT_CHARS", "statustext_chunks"]

STATUSTEXT_CHARS = 50
MAX_CHUNKS = 8  # longer texts are cut (with "...") rather than flood the link


def statustext_chunks(text: str, text_id: int) -> list[tuple[int, int, bytes]]:
    """``(id, chunk_seq, text_bytes)`` for each STATUSTEXT carrying ``text``.

    ``text_id`` (1..255) names a multi-chunk text; it is unused (0) for a single chunk.
    Non-ASCII characters become ``?``.
    """
    data = text.encode("ascii", "replace")
    n = STATUSTEXT_CHARS
    if len(data) <= n:
        return [(0, 0, data)]
    if not 1 <= text_id <= 255:
        raise ValueError(f"text_id must be 1..255 for a chunked text, got {text_id}")
    limit = n * MAX_CHUNKS - 1
    if len(data) > limit:
        data = data[: limit - 3] + b"..."
    chunks = [data[i : i + n] for i in range(0, len(data), n)]
    if len(chunks[-1]) == n:
        chunks.append(b"")
    return [(text_id, seq, chunk) for seq, chunk in enumerate(chunks)]
