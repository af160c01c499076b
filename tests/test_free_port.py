"""``evaluation.sil.free_port``: ports for test and SIL children that no other socket
is handed implicitly (below the OS's ephemeral range) and that are free for TCP and UDP."""

from __future__ import annotations

import socket

import pytest

from evaluation.sil import _ephemeral_range, free_port


def test_ports_lie_below_the_ephemeral_range_and_bind_for_both_kinds():
    low_ephemeral, _ = _ephemeral_range()
    for kind in (socket.SOCK_DGRAM, socket.SOCK_STREAM):
        port = free_port(kind)
        assert 20000 <= port < low_ephemeral, port
        for k in (socket.SOCK_DGRAM, socket.SOCK_STREAM):
            with socket.socket(socket.AF_INET, k) as s:
                s.bind(("127.0.0.1", port))  # raises if it was not free


def test_a_port_in_use_is_never_returned(monkeypatch):
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as held:
        held.bind(("127.0.0.1", free_port()))
        taken = held.getsockname()[1]
        draws = iter([taken, taken, taken + 1])
        monkeypatch.setattr("random.SystemRandom.randint", lambda self, a, b: next(draws))
        assert free_port(socket.SOCK_DGRAM) == taken + 1


def test_draws_are_spread_so_parallel_runs_rarely_meet():
    ports = {free_port() for _ in range(200)}
    assert len(ports) >= 195, len(ports)  # birthday bound over ~12 000 ports: ~1.6 expected


def test_no_free_port_is_a_clear_error(monkeypatch):
    monkeypatch.setattr("evaluation.sil._bindable", lambda port, kind: False)
    with pytest.raises(RuntimeError, match="no free port"):
        free_port()
