"""scripts/phantom_diagrams.py's "before" rule is the old one while it runs, and main's
after: the figures docs/scaling.md quotes from it compare what they say."""

from __future__ import annotations

import math

from script_modules import load_script

from covswarm import protocol
from covswarm.agent.neighborhood import Neighborhood

script = load_script("phantom_diagrams")


def test_old_beacons_stay_in_the_diagram_only_within_the_context() -> None:
    hood = Neighborhood(0, 0.5, 25.0, 0.4)
    hood.on_beacon(protocol.Beacon(id=1, x=0.2, y=0.0, stamp=1.0), 0.0)
    hood.refresh(5.0)  # the beacon is 5 s old, its robot's state never asked for
    main = hood.relevant(5.0, (0.0, 0.0), 1.0, 0.0, 0.5)
    with script.old_beacons_in_diagrams():
        before = hood.relevant(5.0, (0.0, 0.0), 1.0, 0.0, 0.5)
    assert main == {} and before == {1: (0.2, 0.0)}
    assert hood.relevant(5.0, (0.0, 0.0), 1.0, 0.0, 0.5) == {}  # restored
    assert hood.relevant(5.0, (0.0, 0.0), 1.0, 0.0, math.inf) == before
