"""Proximity: OBSTACLE_DISTANCE sectors from the known-space map, and when to send them."""
