"""In-process lockstep harness: plant, camera and the companion's pipeline, no sockets.

This package is the one place where ``plant_sim`` drives ``companion`` code (DESIGN.md,
"Lockstep"): :mod:`plant_sim.lockstep.harness` imports the companion's pure pipeline.
"""
