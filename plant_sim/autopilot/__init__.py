"""An ArduCopter-compatible autopilot emulation: modes, commands, parameters, telemetry, link."""
