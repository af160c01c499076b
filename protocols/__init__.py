"""Shared conventions and wire formats: the only code both processes import."""
