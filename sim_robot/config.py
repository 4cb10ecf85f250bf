"""``RobotConfig``: the ``covswarm robot`` command line as one typed object.

One field per option, with the option's name: the CLI builds it with
``RobotConfig(**options)`` and the launcher turns one back into a command line
(runtime.options.config_argv). Adding an option is a field here and a click option in
sim_robot.process. No zenoh here: the launcher imports it to plan children.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from covswarm.protocol.inbound import MAX_CLOCK_SKEW
from covswarm.tvd.drive import KHEPERA_IV


@dataclass(frozen=True)
class RobotConfig:
    """Every ``covswarm robot`` option; times in s, distances in m, rates in Hz."""

    connect: tuple[str, ...]
    id: int | None = None  # one robot at (x, y, theta) ...
    ids: str | None = None  # ... or several (protocol.keys.parse_ids), one ``pose`` each
    swarm: str = "default"
    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0
    pose: tuple[str, ...] = ()  # "x,y,theta" per robot of ``ids``
    rate: float = 20.0  # integration steps per second
    pose_rate: float = 20.0  # poses published per second
    cmd_timeout: float = 0.5
    time_scale: float = 1.0
    max_clock_skew: float = MAX_CLOCK_SKEW
    max_wheel_speed: float = KHEPERA_IV.max_wheel_speed
    secure: Path | None = None
    verbose: bool = False
