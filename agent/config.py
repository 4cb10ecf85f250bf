"""``AgentProcessConfig``: the ``covswarm agent`` command line as one typed object.

One field per option, with the option's name (``--pose-loss`` is ``pose_loss``): the CLI
builds it with ``AgentProcessConfig(**options)``, the launcher turns one back into a command
line (runtime.options.config_argv), and :meth:`AgentProcessConfig.brain` is the brains'
AgentConfig. Adding an option is a field here (and in AgentConfig if the brain reads it) and
a click option in agent.main. No zenoh here: the launcher imports it to plan children.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from covswarm.agent.brain import AgentConfig
from covswarm.tvd.drive import KHEPERA_IV, DiffDrive

_BRAIN = AgentConfig()  # the brain's defaults are the command's


@dataclass(frozen=True)
class AgentProcessConfig:
    """Every ``covswarm agent`` option; times in s, distances in m, rates in Hz."""

    connect: tuple[str, ...]
    rate: float  # control periods per second (required: a plan always says it)
    id: int | None = None  # one brain ...
    ids: str | None = None  # ... or several (protocol.keys.parse_ids), exactly one of them
    swarm: str = "default"
    tick_phase: float | None = None  # fraction of a period (runtime.clock.Ticker's phase)
    time_scale: float = 1.0
    kappa: float | None = _BRAIN.kappa
    feedforward: bool = _BRAIN.feedforward
    law: str = _BRAIN.law
    stale_timeout: float = _BRAIN.stale_timeout
    state_period: float = _BRAIN.state_period
    beacon_period: float = _BRAIN.beacon_period
    beacon_timeout: float = _BRAIN.beacon_timeout
    max_tile_radius: int = _BRAIN.max_tile_radius
    max_extrapolation: float = _BRAIN.max_extrapolation
    linger: float = _BRAIN.linger
    max_clock_skew: float = _BRAIN.max_clock_skew
    max_wheel_speed: float = KHEPERA_IV.max_wheel_speed
    pose_loss: float = _BRAIN.pose_loss
    pose_delay: float = _BRAIN.pose_delay
    pose_seed: int = _BRAIN.pose_seed
    prediction: bool = _BRAIN.prediction
    cmd_timeout: float = _BRAIN.cmd_timeout
    command_latency: float = _BRAIN.command_latency
    projection_distance: float = _BRAIN.projection_distance
    safety: bool = _BRAIN.safety
    safety_margin: float = _BRAIN.safety_margin
    body_diameter: float = KHEPERA_IV.body_diameter
    # (xmin, xmax, ymin, ymax) m: a domain outside it is refused (None: no check)
    workspace: tuple[float, float, float, float] | None = field(default=None, metadata={"nargs": 4})
    secure: Path | None = None
    verbose: bool = False
    # s of sleep added to every control step (agent.faults.delay_steps: a starved process)
    fault_step_delay: float = 0.0

    def brain(self) -> AgentConfig:
        """The AgentConfig every brain of this process runs with."""
        return AgentConfig(
            kappa=self.kappa,
            feedforward=self.feedforward,
            law=self.law,
            stale_timeout=self.stale_timeout,
            state_period=self.state_period,
            beacon_period=self.beacon_period,
            beacon_timeout=self.beacon_timeout,
            max_tile_radius=self.max_tile_radius,
            max_extrapolation=self.max_extrapolation,
            linger=self.linger,
            max_clock_skew=self.max_clock_skew,
            robot=DiffDrive(max_wheel_speed=self.max_wheel_speed, body_diameter=self.body_diameter),
            pose_loss=self.pose_loss,
            pose_delay=self.pose_delay,
            pose_seed=self.pose_seed,
            prediction=self.prediction,
            cmd_timeout=self.cmd_timeout,
            command_latency=self.command_latency,
            projection_distance=self.projection_distance,
            safety=self.safety,
            safety_margin=self.safety_margin,
            workspace=self.workspace,
        )
