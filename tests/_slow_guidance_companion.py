"""Test helper: ``python -m _slow_guidance_companion <companion args>`` is the companion
with an artificial cost of ``SLOW_GUIDANCE_S`` (0.2 s) in every guidance step (issue 34).

A sleep, not a spin: the cost is the same on an idle and on a loaded machine, so the
share of frames a reporting-only companion processes tells whether guidance ran on them.
"""

from __future__ import annotations

import os
import sys
import time

from companion.__main__ import main
from companion.guidance import Guidance

_step = Guidance.step


def _slow_step(self, **kwargs):
    time.sleep(float(os.environ.get("SLOW_GUIDANCE_S", "0.2")))
    return _step(self, **kwargs)


if __name__ == "__main__":
    Guidance.step = _slow_step
    sys.exit(main())
