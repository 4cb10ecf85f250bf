"""A coordinator core on the warehouse, driven without a network: what the world, goto
and route tests of the coordinator share."""

from __future__ import annotations

from functools import cache

from covswarm.coordinator.core import WAITING, CoordinatorCore, CoordinatorSettings, ReplySteer
from covswarm.mission.scenario_files import load_scenario
from covswarm.mission.scenarios import Scenario
from covswarm.protocol import alive_key
from covswarm.protocol.steering import SteerReply, SteerRequest

SWARM = "world-test"
WALL0 = 1.7e9


@cache
def warehouse() -> Scenario:
    return load_scenario("warehouse")


def make_core(agents: int = 3, duration: float = 60.0) -> CoordinatorCore:
    settings = CoordinatorSettings(
        scenario=warehouse(), swarm=SWARM, agents=agents, duration=duration, kappa=2.0,
        rate=20.0, sample_rate=10.0, feedforward=True, tile_size=0.5,
    )  # fmt: skip
    return CoordinatorCore(settings, cost_clock=lambda: 0.0, cpu_clock=lambda: 0.0)


def join(core: CoordinatorCore, ids, now: float = 0.0) -> None:
    for i in ids:
        for role in ("robot", "agent"):
            core.on_liveliness(alive_key(SWARM, role, i), True, now, WALL0 + now)


def run_until_started(core: CoordinatorCore) -> float:
    join(core, range(core.settings.agents))
    now = 0.0
    while core.phase.state == WAITING:
        core.tick(now, WALL0 + now)
        now = round(now + 0.05, 10)
    return now - 0.05


def steer(core: CoordinatorCore, request: SteerRequest, now: float, who: str | None = None):
    (reply,) = [a for a in core.on_steer(request.encode(), now, WALL0 + now, who) if
                isinstance(a, ReplySteer)]  # fmt: skip
    return SteerReply.decode(reply.payload)
