"""scripts/beside_slide.py's "before" rule is the old one while it runs, and main's after:
the figures covswarm.tvd.drive and docs/scaling.md quote from it compare what they say."""

from __future__ import annotations

import math

from script_modules import load_script

slide_escape = load_script("slide_escape")
script = load_script("beside_slide")


def test_before_a_robot_beside_its_blocker_waits_only_within_the_context() -> None:
    # A still robot 75 degrees off its heading: main slides from the first stopped step;
    # before, SLIDE_AFTER (1 s) kept it standing for the first 0.6 s.
    main, _, _ = slide_escape.drive_past(math.radians(75.0), seconds=0.6)
    with script.slides_only_after_waiting():
        before, _, _ = slide_escape.drive_past(math.radians(75.0), seconds=0.6)
    again, _, _ = slide_escape.drive_past(math.radians(75.0), seconds=0.6)  # restored
    assert before.counters.slid == 0 < main.counters.slid == again.counters.slid
