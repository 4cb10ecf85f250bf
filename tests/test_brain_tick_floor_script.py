"""scripts/brain_tick_floor.py measures what docs/scaling.md says it does: a second of the
pack's own payloads (a tenth of its states with stats), the decode beside msgpack alone, and
Zenoh's costs over a router of its own on loopback."""

from __future__ import annotations

import math

from script_modules import load_script

from covswarm.agent import brain
from covswarm.deploy import bench
from covswarm.tvd import control

script = load_script("brain_tick_floor")


def test_the_messages_are_a_second_of_the_packs_own_payloads() -> None:
    layout = bench.make_layout(30, "cvt", 0, spacing=bench.BRAIN_TICK_SPACING)
    costs = script.messages(30, layout)
    # each brain sends stats with one state a second: one period in ten
    assert 5.0 <= costs["AgentStates with stats (%)"] <= 20.0
    # the decode unpacks, then checks and derives the facts: never cheaper than unpacking
    assert costs["AgentState: decode (checks, StateFacts)"] > costs["AgentState: msgpack unpack"]
    assert all(math.isfinite(value) and value > 0.0 for value in costs.values())


def test_python_calls_and_zenoh_costs_are_counted() -> None:
    layout = bench.make_layout(20, "cvt", 0, spacing=bench.BRAIN_TICK_SPACING)
    assert script.calls_per_brain_tick(20, layout) > 50.0
    math_costs = script.math_by_batch(20, layout, (8, 20))
    assert set(math_costs) == {8, 20}
    assert all(steps > 0.0 and filters > 0.0 for steps, filters in math_costs.values())
    # the pack's functions are its own again afterwards
    assert script.pack_module.local_steps is control.local_steps
    assert script.pack_module.filter_all is brain.filter_all
    zenoh = script.zenoh_costs(publishers=20, rounds=3)
    assert all(math.isfinite(value) and value > 0.0 for value in zenoh.values())
