"""Viewing what the companion sees: Rerun logging and the geometry it draws."""
