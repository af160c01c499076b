"""Per-peer rate limits for the requests a peer can make the autopilot work for (pure).

A flood of PARAM_REQUEST_LIST, mission requests, commands or TIMESYNCs from one peer must
not starve the others of heartbeats and telemetry. :class:`RequestLimiter` keeps a token
bucket per peer (MAVLink source system/component) and one for all peers together, so that
spoofing many source ids buys no more than the shared budget. What exceeds a bucket is
dropped before it is queued, counted by message type, and logged by the caller. Time is
passed in (wall seconds); nothing here reads a clock.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

__all__ = ["RateLimits", "RequestLimiter", "TokenBucket"]


class TokenBucket:
    """``rate_per_s`` tokens per second, at most ``burst`` stored; one token per request."""

    __slots__ = ("_burst", "_last_s", "_rate", "_tokens")

    def __init__(self, rate_per_s: float, burst: float, now_s: float) -> None:
        if not (rate_per_s > 0 and burst >= 1):
            raise ValueError(f"rate_per_s must be > 0 and burst ≥ 1, got {rate_per_s}, {burst}")
        self._rate = float(rate_per_s)
        self._burst = float(burst)
        self._tokens = float(burst)
        self._last_s = now_s

    def take(self, now_s: float, cost: float = 1.0) -> bool:
        """Take ``cost`` tokens if there are enough; False (nothing taken) otherwise."""
        elapsed = now_s - self._last_s
        if elapsed > 0:
            self._tokens = min(self._burst, self._tokens + elapsed * self._rate)
            self._last_s = now_s
        if self._tokens >= cost:
            self._tokens -= cost
            return True
        return False


@dataclass(frozen=True)
class RateLimits:
    """Budgets [requests/s] and bursts; every type not listed in ``costs`` costs 1 token
    of the peer's bucket; the shared bucket counts each message as 1."""

    # a companion at 30 Hz of frames and --speedup 10 sends ~300 setpoints/s of wall time
    per_peer_rate: float = 1000.0
    per_peer_burst: float = 2000.0
    total_rate: float = 3000.0
    total_burst: float = 6000.0
    max_peers: int = 64  # least recently seen peers are forgotten beyond this
    #: what one message of these types costs (they make the autopilot send a lot)
    costs: tuple[tuple[str, float], ...] = (
        ("PARAM_REQUEST_LIST", 100.0),
        ("MISSION_REQUEST_LIST", 10.0),
        ("MISSION_CLEAR_ALL", 10.0),
        ("MISSION_COUNT", 10.0),
    )
    #: never limited: cost nothing to serve
    exempt: frozenset[str] = frozenset({"HEARTBEAT"})


class RequestLimiter:
    """Decides, per incoming message, whether the autopilot serves it."""

    def __init__(self, limits: RateLimits | None = None) -> None:
        self.limits = limits or RateLimits()
        self._costs = dict(self.limits.costs)
        self._peers: OrderedDict[tuple[int, int], TokenBucket] = OrderedDict()
        self._total: TokenBucket | None = None
        self.dropped: dict[str, int] = {}

    def allow(self, peer: tuple[int, int], msg_type: str, now_s: float) -> bool:
        """True to serve the message; False: drop it (counted in :attr:`dropped`)."""
        lim = self.limits
        if msg_type in lim.exempt:
            return True
        cost = self._costs.get(msg_type, 1.0)
        bucket = self._peers.get(peer)
        if bucket is None:
            bucket = TokenBucket(lim.per_peer_rate, lim.per_peer_burst, now_s)
            self._peers[peer] = bucket
            while len(self._peers) > lim.max_peers:
                self._peers.popitem(last=False)
        else:
            self._peers.move_to_end(peer)
        if self._total is None:
            self._total = TokenBucket(lim.total_rate, lim.total_burst, now_s)
        # the shared budget counts messages: expensive types are a per-peer matter
        if bucket.take(now_s, cost) and self._total.take(now_s):
            return True
        self.dropped[msg_type] = self.dropped.get(msg_type, 0) + 1
        return False
