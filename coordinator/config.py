"""``CoordinatorConfig``: the coordinator's command line as one typed object.

One field per ``covswarm coordinator`` option, with the option's name (``--sample-rate`` is
``sample_rate``): the CLI builds it with ``CoordinatorConfig(**options)`` and the launcher
turns one back into a command line (deploy.plan.config_argv), so adding an option is a
field here and a click option in coordinator.main. ``None`` means "the scenario's value"
(agents, duration, kappa) or "derived" (tile_size, max_domain_speed): see
coordinator.core.CoordinatorSettings, which resolves them against the loaded scenario.
No zenoh and no scenario loading here: the launcher imports it to plan children.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

MISSION_FILE = "mission.json"  # in --out: the start wall time, for --resume
STEERING_JOURNAL = "steering.jsonl"  # in --out: accepted steering requests, for --resume
SCRIPT_FILE = "script.json"  # in --out: where the script's clock stands, for --resume
DEPLOY_TIMEOUT = 60.0  # s of mission time a deploy hold lasts at most, by default


def planned_wall(duration: float, deploy_timeout: float, time_scale: float) -> float:
    """Wall seconds a run may last: its mission (``duration``, s of mission time) and its
    longest deploy hold (``deploy_timeout``, s), at ``time_scale`` mission s per wall s."""
    return (duration + deploy_timeout) / time_scale


@dataclass(frozen=True)
class CoordinatorConfig:
    """Every ``covswarm coordinator`` option; times in s, distances in m, rates in Hz."""

    swarm: str
    out: Path
    scenario: str = "passage"  # a built-in name or a .toml file
    connect: tuple[str, ...] = ()
    agents: int | None = None
    duration: float | None = None
    rate: float = 20.0  # Domain broadcasts per second
    sample_rate: float = 10.0  # e_a samples per second (at most)
    kappa: float | None = None
    tile_size: float | None = None
    feedforward: bool = True  # how the agents run (recorded in the summary)
    law: str = "da"  # the agents' control law (recorded in the summary)
    resume: bool = False
    max_domain_speed: float | None = None
    record: bool = True
    record_states: bool = True  # the agents' AgentStates in run.mcap (/agents/states)
    foxglove: int | None = None  # live view port (0: a free one)
    seed: int | None = None  # the robots' start seed, recorded in run.mcap
    time_scale: float = 1.0
    secure: Path | None = None
    # The agents' control rate (Hz): what their reported rates are held against (pacing).
    agent_rate: float = 10.0
    pace: bool = True  # slow the mission's script to what the team holds (coordinator.pace)
    # m: the deploy hold (coordinator.pace): S waits at S(0) until e_a is this low
    deploy_error: float | None = None
    deploy_timeout: float = DEPLOY_TIMEOUT
    deploy_kappa: float | None = None  # 1/s: the gain broadcast during the hold (None: kappa)
