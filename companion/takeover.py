"""Am I the only one steering this autopilot? Detect other setpoint sources (pure).

Two companions on one autopilot (the same default ids, or a second onboard controller, or a
ground station streaming SET_POSITION_TARGET_*) fight over the vehicle; neither would
notice. :class:`TakeoverGuard` watches what the link shows:

* a HEARTBEAT carrying *our own* system/component ids but another instance id (every
  companion puts a random 32-bit instance id in its heartbeat's ``custom_mode``): a twin.
  The twin that is already steering (heartbeat MAV_STATE_ACTIVE) keeps control; if both or
  neither are, the higher instance id yields. So exactly one steers.
* a SET_POSITION_TARGET_* / SET_ATTITUDE_TARGET addressed to our autopilot from any other
  system/component: someone else is steering; we refuse while they do.

Refusal lasts until nothing of the kind was seen for ``quiet_s`` (wall time). Time is passed
in; no I/O here.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["SETPOINT_MESSAGES", "TakeoverGuard", "TakeoverState"]

#: messages by which another source steers the vehicle
SETPOINT_MESSAGES = frozenset(
    {
        "SET_POSITION_TARGET_LOCAL_NED",
        "SET_POSITION_TARGET_GLOBAL_INT",
        "SET_ATTITUDE_TARGET",
    }
)


@dataclass(frozen=True)
class TakeoverState:
    """Whether we may steer, and why not."""

    blocked: bool
    reason: str = ""


class TakeoverGuard:
    """Decide whether this companion may steer, from what other sources show on the link.

    Parameters
    ----------
    own_ids : our (system, component).
    instance_id : our random instance id (heartbeat ``custom_mode``).
    quiet_s : wall seconds without a conflicting source before we are alone again.
    """

    def __init__(self, own_ids: tuple[int, int], instance_id: int, quiet_s: float = 3.0) -> None:
        self.own_ids = own_ids
        self.instance_id = instance_id
        self.quiet_s = quiet_s
        self._twin_until_s = -1.0
        self._twin_yield = False
        self._foreign_until_s = -1.0
        self._foreign: tuple[int, int] | None = None
        self._twin_id: int | None = None
        self.conflicts = 0

    def on_twin_heartbeat(
        self, now_s: float, twin_instance_id: int, twin_active: bool, we_active: bool
    ) -> None:
        """A heartbeat with our ids; ignored if it is our own (same instance id)."""
        if twin_instance_id == self.instance_id:
            return
        if twin_active != we_active:
            self._twin_yield = twin_active
        else:
            self._twin_yield = twin_instance_id < self.instance_id
        if now_s > self._twin_until_s:
            self.conflicts += 1
        self._twin_until_s = now_s + self.quiet_s
        self._twin_id = twin_instance_id

    def on_foreign_setpoint(self, now_s: float, source: tuple[int, int]) -> None:
        """A setpoint for our autopilot from another system/component."""
        if source == self.own_ids:
            return
        if now_s > self._foreign_until_s:
            self.conflicts += 1
        self._foreign_until_s = now_s + self.quiet_s
        self._foreign = source

    def state(self, now_s: float) -> TakeoverState:
        if now_s <= self._foreign_until_s and self._foreign is not None:
            sysid, compid = self._foreign
            return TakeoverState(True, f"setpoints from {sysid}/{compid} for our autopilot")
        if now_s <= self._twin_until_s and self._twin_yield:
            sysid, compid = self.own_ids
            return TakeoverState(
                True, f"another companion on ids {sysid}/{compid} (instance {self._twin_id:08x})"
            )
        return TakeoverState(False)

    def twin_present(self, now_s: float) -> bool:
        """A twin was seen recently (whether or not we yield to it)."""
        return now_s <= self._twin_until_s
