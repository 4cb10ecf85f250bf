"""What the coordinator answers a goto and a request through a wall in the warehouse.

The coordinator's own steering (sans-IO, no processes): the ``warehouse`` built-in for a
team of 6 at its default speed limit, S at its start (the scenario's S(0), in the left
room), one ``goto (2.7, 0.1)`` (the right room, through the 1.1 m door) and one translation
5 m east (straight through the dividing wall). Prints each answer as ``covswarm steer``
would, with the route. Run from the repository root:

    python scripts/warehouse_goto.py
"""

from __future__ import annotations

import numpy as np

from covswarm.coordinator.core import CoordinatorSettings
from covswarm.coordinator.steering import Steering, world_check
from covswarm.mission.scenario_files import load_scenario
from covswarm.protocol.steering import SteerRequest

AGENTS = 6


def main() -> None:
    scenario = load_scenario("warehouse")
    settings = CoordinatorSettings(
        scenario=scenario, swarm="demo", agents=AGENTS, duration=scenario.duration,
        kappa=scenario.kappa, rate=20.0, sample_rate=10.0, feedforward=True,
    )  # fmt: skip
    start = scenario.domain(0.0)[0]
    for request in (
        SteerRequest("goto", goal=(2.7, 0.1)),
        SteerRequest("translate", dx=5.0, dy=0.0),
    ):
        steering = Steering(
            lambda t: (start.copy(), np.zeros_like(start)),
            settings.steering_limits(),
            checks=(world_check(scenario.world),),
            world=scenario.world,
        )
        reply = steering.handle(request.encode(), 0.0, 1.7e9, True)
        if not reply.accepted:
            print(f"refused: {reply.reason}")
            continue
        print(f"accepted: {request.describe()}, {reply.duration:.2f} s")
        print("route: " + " -> ".join(f"({x:.3f}, {y:.3f}) x{s:.2f}" for x, y, s in reply.route))


if __name__ == "__main__":
    main()
