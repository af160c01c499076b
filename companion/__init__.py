"""The onboard avoidance service: stereo frames in, MAVLink aiming points out."""
