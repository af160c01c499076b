"""Record the companion core's inputs and outputs to MCAP; replay them through a fresh core."""
