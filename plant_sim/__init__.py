"""The software-in-the-loop plant: quadrotor physics, flight control, camera and autopilot."""
