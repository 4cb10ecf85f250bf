"""scripts/discovery_start.py's "before" rule is the old one while it runs, and main's after:
the figures docs/scaling.md quotes from it compare what they say."""

from __future__ import annotations

from script_modules import load_script

from covswarm.agent import brain as brain_module

script = load_script("discovery_start")


def test_before_the_diagram_takes_only_young_beacons_within_the_context() -> None:
    assert brain_module.diagram_trust(5.0, 4.0) == brain_module.IDLE_STEP_PERIOD
    with script.young_beacons_only():
        assert brain_module.diagram_trust(5.0, 4.0) == brain_module.BEACON_TRUST
    assert brain_module.diagram_trust(5.0, 4.0) == brain_module.IDLE_STEP_PERIOD


def test_before_the_lone_brain_of_the_dead_brains_case_names_no_neighbour() -> None:
    results = script.run_case("passage", 6, 10.0, (0, 3), seed=0, duration=0.2)
    before, main = (results[rule] for rule in script.RULES)
    assert before.stats[1]["neighbors"] == 0
    assert main.stats[1]["neighbors"] >= 2
