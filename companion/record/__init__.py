"""Record the companion's inputs to MCAP and replay them through the same pipeline."""
