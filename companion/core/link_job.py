"""Link and heartbeats: link up / lost / silent, our heartbeat, handler errors.

A component of :class:`~companion.core.CompanionCore` that owns its state: whether the
link is up and when the autopilot was last heard, until when we only listen (another
companion's heartbeat must have had a chance to arrive, :mod:`companion.takeover`), our
heartbeat's schedule, the silence report and the kinds of handler errors already logged.
Typed in: the time of each autopilot message, the companion's state (for our heartbeat)
and the timer. Out: the heartbeat, the link's events and log lines in the step's
:class:`~companion.core.outbox.Outbox`, and booleans the core acts on: the link came up
(streams at once), the link was lost (everything learnt about the vehicle goes). Which
job reads which message is the core's routing. Pure: wall time comes with each input.
"""

from __future__ import annotations

import logging
import math

from companion.config import FailsafeConfig, LinkConfig
from companion.core.counters import CoreCounters
from companion.core.outbox import Outbox
from companion.link.messages import CompanionState, heartbeat_message

_log = logging.getLogger("companion")

LISTEN_BEFORE_STEERING_S = 2.5  # > 2 heartbeat periods of another companion [s wall]
_SILENCE_FIRST_S = 3.0  # no autopilot this long: said [s wall]
_SILENCE_REPEAT_S = 5.0  # and again every this long [s wall]

__all__ = ["LISTEN_BEFORE_STEERING_S", "LinkJob", "statustext"]


class LinkJob:
    """The link: up and lost, our heartbeat, the silence report.

    Parameters
    ----------
    link : LinkConfig
        The URL, ids, heartbeat period, whether messages are signed.
    failsafe : FailsafeConfig
        ``link_timeout_s``: silence before the link is lost [s wall].
    instance_id : int
        This companion's 32-bit id, in our heartbeat's ``custom_mode``.
    out : Outbox
        Where the heartbeat and the link's events go (the core's, per step).
    counters : CoreCounters
        ``link_losses``, ``handler_errors``; ``mavlink_sent`` is read for the report.
    """

    def __init__(
        self,
        link: LinkConfig,
        failsafe: FailsafeConfig,
        instance_id: int,
        out: Outbox,
        counters: CoreCounters,
    ) -> None:
        self._link = link
        self._timeout_s = failsafe.link_timeout_s
        self._instance_id = instance_id
        self._out = out
        self._counters = counters
        self._signing = link.signing_key is not None
        self.up = False
        self._last_rx_s = -math.inf
        self.listen_until_s = math.inf  # no steering before the link was heard a while
        self._next_heartbeat_s = 0.0
        self._silent_since_s: float | None = None
        self._silence_reported_s = -math.inf
        self._handler_error_kinds: set[str] = set()

    def alive(self, now_s: float) -> bool:
        """An autopilot message at ``now_s``; True: the link just came up."""
        self._last_rx_s = now_s
        self._silent_since_s = None
        if self.up:
            return False
        self.up = True
        # listen before steering: another companion's heartbeat (1 Hz, forwarded by the
        # autopilot) must have had a chance to arrive (companion.takeover)
        self.listen_until_s = now_s + LISTEN_BEFORE_STEERING_S
        self._out.event("link_up", url=self._link.url)
        _log.info("autopilot link up on %s", self._link.url)
        return True

    def heartbeat_due(self, now_s: float) -> bool:
        """Our heartbeat is due (:meth:`send_heartbeat`)."""
        return now_s >= self._next_heartbeat_s

    def send_heartbeat(self, state: CompanionState, now_s: float) -> None:
        """Our heartbeat with the companion's ``state``; the next one a period later."""
        self._out.send(heartbeat_message(state, self._instance_id))
        self._next_heartbeat_s = now_s + self._link.heartbeat_period_s

    def check_lost(self, now_s: float) -> bool:
        """True: the link was up and silent for ``link_timeout_s``, now lost (said)."""
        if not self.up or now_s - self._last_rx_s <= self._timeout_s:
            return False
        self.up = False
        self._counters.link_losses += 1
        _log.warning(
            "autopilot link lost: nothing for %.1f s (wall); stopped commanding, waiting",
            now_s - self._last_rx_s,
        )
        self._out.event("link_lost", silent_s=round(now_s - self._last_rx_s, 3))
        return True

    def report_silence(self, now_s: float) -> None:
        """No autopilot: say so every few seconds, with the likely causes."""
        if self._silent_since_s is None:
            self._silent_since_s = now_s
            return
        silent = now_s - self._silent_since_s
        if silent < _SILENCE_FIRST_S or now_s - self._silence_reported_s < _SILENCE_REPEAT_S:
            return
        self._silence_reported_s = now_s
        hint = (
            "MAVLink signing is on: an autopilot with another key (or none) ignores every "
            "message we send"
            if self._signing
            else "check the URL and that the autopilot sends to us"
        )
        cfg = self._link
        _log.error(
            "no message from autopilot %d/%d on %s for %.0f s (%d sent): %s",
            cfg.target_system,
            cfg.target_component,
            cfg.url,
            silent,
            self._counters.mavlink_sent,
            hint,
        )
        self._out.event("no_autopilot", silent_s=round(silent, 1), signing=self._signing)

    def handler_error(self, msg, exc: Exception) -> None:
        """A handler failed on ``msg``: counted, logged once per message type and error."""
        self._counters.handler_errors += 1
        kind = f"{msg.get_type()}:{type(exc).__name__}"
        if kind not in self._handler_error_kinds:
            self._handler_error_kinds.add(kind)
            _log.error(
                "handling %s failed (%s: %s); message dropped", kind, type(exc).__name__, exc
            )


def statustext(msg) -> str:
    """The STATUSTEXT's text, printable ASCII only (raw bytes never reach the log)."""
    text = msg.text if isinstance(msg.text, str) else msg.text.decode("ascii", "replace")
    text = text.split("\x00", 1)[0]
    return "".join(c if " " <= c <= "~" else "?" for c in text)
