"""A companion on a quarter of one core against plant-sim at 1× (issue 32 item 5;
the verdicts are in ``tests/_starved.py``)."""

from __future__ import annotations

import pytest
from _starved import SCENES, check, fly_starved, skip_unless_starvable


@pytest.mark.slow
@pytest.mark.parametrize("scene", sorted(SCENES))
def test_starved_companion_at_1x(scene, tmp_path):
    skip_unless_starvable()
    check(fly_starved(scene, 1.0, tmp_path))
