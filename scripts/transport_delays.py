"""Where a live run's delays are: stamp-to-receipt of poses, commands and AgentStates.

Usage: .venv/bin/python scripts/transport_delays.py ENDPOINT SWARM [--ids 0-999:50]
       [--every 10] [--duration 60]

Joins a running ``covswarm run`` (ENDPOINT and SWARM as its launcher prints them: "swarm
SWARM on ENDPOINT") as one more Zenoh client on the same host, subscribes to the poses,
wheel commands and AgentStates of the robots ``--ids`` (a protocol id range with an
optional ``:step``), and every ``--every`` s prints, per kind, the p10/p50/p90/p99 in ms of:

- ``pose``: its receipt here minus its stamp (robot process -> router -> here);
- ``command``: likewise for wheel commands (agent process -> router -> here);
- ``steered pose age``: a moving command's stamp minus the stamp of the pose it was
  computed from (WheelCommand.pose_stamp): how old its own robot's pose was to a brain
  that steered; ``stop pose age``: the same for commands of (0, 0), which a packed process
  sends for a brain whose turn came late (covswarm.agent.pack), a gap after its last pose;
- ``state``: AgentStates, as poses.

Same host, same clock: the figures are transport and queueing, not clock offsets.
docs/scaling.md quotes it (1000 robots on two cores, 28 Nov 2026).
"""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Callable

import click
import numpy as np
import zenoh

from covswarm import protocol
from covswarm.protocol import session_config
from covswarm.protocol.keys import parse_ids

KINDS = ("pose", "command", "steered pose age", "stop pose age", "state")


def id_range(spec: str) -> list[int]:
    """``first-last`` or ``first-last:step`` as a list of ids."""
    span, _, step = spec.partition(":")
    ids = parse_ids(span)
    return ids[:: int(step)] if step else ids


@click.command()
@click.argument("endpoint")
@click.argument("swarm")
@click.option("--ids", default="0-999:50", show_default=True, help="Robots to follow.")
@click.option("--every", type=click.FloatRange(1.0), default=10.0, show_default=True)
@click.option("--duration", type=click.FloatRange(1.0), default=60.0, show_default=True)
def main(endpoint: str, swarm: str, ids: str, every: float, duration: float) -> None:
    delays: dict[str, list[float]] = defaultdict(list)

    def on_pose(sample: zenoh.Sample) -> None:
        pose = protocol.Pose.decode(sample.payload.to_bytes())
        delays["pose"].append(time.time() - pose.stamp)

    def on_command(sample: zenoh.Sample) -> None:
        received = time.time()
        command = protocol.WheelCommand.decode(sample.payload.to_bytes())
        delays["command"].append(received - command.stamp)
        moving = command.left != 0.0 or command.right != 0.0
        kind = "steered pose age" if moving else "stop pose age"
        delays[kind].append(command.stamp - command.pose_stamp)

    def on_state(sample: zenoh.Sample) -> None:
        state = protocol.AgentState.decode(sample.payload.to_bytes())
        delays["state"].append(time.time() - state.stamp)

    malformed = 0

    def counted(handler: Callable[[zenoh.Sample], None]) -> Callable[[zenoh.Sample], None]:
        """``handler``, with a payload that does not decode counted instead of raised."""

        def receive(sample: zenoh.Sample) -> None:
            nonlocal malformed
            try:
                handler(sample)
            except protocol.ProtocolError:
                malformed += 1

        return receive

    on_pose, on_command, on_state = counted(on_pose), counted(on_command), counted(on_state)
    with zenoh.open(session_config([endpoint])) as session:
        subscribers = []
        for rid in id_range(ids):
            subscribers += [
                session.declare_subscriber(protocol.pose_key(swarm, rid), on_pose),
                session.declare_subscriber(protocol.cmd_key(swarm, rid), on_command),
                session.declare_subscriber(protocol.agent_state_key(swarm, rid), on_state),
            ]
        click.echo("| time | kind | samples | p10 ms | p50 ms | p90 ms | p99 ms |")
        click.echo("|---|---|---|---|---|---|---|")
        end = time.monotonic() + duration
        while time.monotonic() < end:
            time.sleep(min(every, max(end - time.monotonic(), 0.0)))
            taken = {kind: delays.pop(kind, []) for kind in KINDS}
            for kind, values in taken.items():
                if not values:
                    continue
                p10, p50, p90, p99 = np.percentile(np.array(values) * 1e3, [10, 50, 90, 99])
                click.echo(
                    f"| {time.strftime('%H:%M:%S')} | {kind} | {len(values)} "
                    f"| {p10:.0f} | {p50:.0f} | {p90:.0f} | {p99:.0f} |"
                )
        if malformed:
            click.echo(f"{malformed} malformed samples dropped")
        for subscriber in subscribers:
            subscriber.undeclare()


if __name__ == "__main__":
    main()
