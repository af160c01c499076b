"""A companion on a quarter of one core against plant-sim at 1× (issue 32 item 5;
the verdicts are in ``tests/_starved.py``). At real time the two scenes of the issue's
evidence (the paper's, the wall behind); the Monte Carlo scenes fly at 3×
(``test_starved_companion_3x.py``), where the companion is three times hungrier, to keep
the suite's wall time (each real-time flight costs ~40 s)."""

from __future__ import annotations

import pytest
from _starved import check, fly_starved, skip_unless_starvable


@pytest.mark.slow
@pytest.mark.parametrize("scene", ["paper", "wall_behind"])
def test_starved_companion_at_1x(scene, tmp_path):
    skip_unless_starvable()
    check(fly_starved(scene, 1.0, tmp_path))
