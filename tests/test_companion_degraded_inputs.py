"""Issue 32 on the pure core: measured data age, holds without mode flapping, safe hold targets.

The scripted ArduCopter of ``test_companion_core`` (host and autopilot clocks at one rate,
frames on the autopilot clock, DO_SET_MODE obeyed at once).
"""

from __future__ import annotations

import pytest
from test_companion_core import Rig

from companion.config import CompanionConfig


def _steering_rig(config: CompanionConfig | None = None) -> Rig:
    rig = Rig(config)
    rig.run(3.0)  # listen 2.5 s before steering
    assert rig.events("steering"), rig.outputs[-5:]
    return rig


def test_core_measures_the_data_age_of_its_commands_and_budgets_it():
    """Frames captured 0.4 s before they are handed over: the data age p50/p99 is 0.4 s,
    the latency budget 0.4 s + unmeasured_latency_s, the status document says so."""
    rig = _steering_rig()
    env = rig.core.config.envelope
    doc = rig.statuses()[-1]["pipeline"]
    assert doc["latency_budget_s"] == env.latency_s  # an idle companion: the floor
    assert doc["rate_hz"] == pytest.approx(100.0 / 3.0, rel=0.02)  # a frame every 30 ms
    rig.frame_lag_s = 0.4
    rig.run(3.0)
    doc = rig.statuses()[-1]["pipeline"]
    # "now" on the autopilot clock is its newest telemetry stamp (every 20 ms): the age is
    # the lag less the time since that stamp, so up to 20 ms short
    assert 380.0 <= doc["data_age_p50_ms"] <= doc["data_age_p99_ms"] <= 400.0, doc
    assert doc["latency_budget_s"] == pytest.approx(
        doc["data_age_p99_ms"] * 1e-3 + env.unmeasured_latency_s, abs=0.011
    )
    assert doc["speed_limit_mps"] is not None
    assert "mode_requests" in rig.statuses()[-1]
    assert "latency budget 0.50 s" in rig.core.progress_text()
