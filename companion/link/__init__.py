"""MAVLink side of the companion: one module per concern.

* :mod:`~companion.link.connection` — pymavlink transport, signing, counters (sockets).
* :mod:`~companion.link.flavour` — ArduPilot / PX4 from the heartbeat, their modes (pure).
* :mod:`~companion.link.mode_watch` — engage, hold, release on a pilot's takeover (pure).
* :mod:`~companion.link.setpoints` — SET_POSITION_TARGET_LOCAL_NED and its timing (pure).
* :mod:`~companion.link.takeoff` — ``--takeoff-alt``: probe, GUIDED, arm, take off, climb (pure).
* :mod:`~companion.link.messages` — heartbeat, commands, STATUSTEXT, TIMESYNC (pure).
"""
