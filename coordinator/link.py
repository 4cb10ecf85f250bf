"""The Zenoh side of the coordinator: its token, subscriptions, queryable and publishers,
and the actions of its core (coordinator.core.CoordinatorCore).

Subscribers and the steering queryable use channels the loop polls once per tick, so no
Python callback thread exists; everything the core decides happens in the loop.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import zenoh

from covswarm.coordinator.config import SCRIPT_FILE, STEERING_JOURNAL
from covswarm.coordinator.core import (
    Action,
    CoordinatorCore,
    Finished,
    JournalSteering,
    MissionStarted,
    PublishDomain,
    PublishStatus,
    PublishWorld,
    RecordScriptClock,
    ReplySteer,
)
from covswarm.coordinator.steering import requester_key
from covswarm.protocol import (
    alive_key,
    alive_selector,
    all_agent_states_selector,
    all_poses_selector,
    domain_key,
    status_key,
    steer_key,
    world_key,
    world_map_key,
)
from covswarm.runtime.clock import StopFlag, Ticker

log = logging.getLogger("covswarm.coordinator")

STEER_QUEUE = 64  # steering queries held between two ticks
MAP_QUEUE = 16  # map picture queries held between two ticks


class CoordinatorLink:
    """The coordinator's subscriptions, publishers and loop on one open zenoh session."""

    def __init__(
        self, session: zenoh.Session, core: CoordinatorCore, mission_file: Path | None = None
    ) -> None:
        """``mission_file``: where MissionStarted records the start wall time (for
        --resume); the steering journal lives beside it."""
        self.core = core
        swarm, n = core.settings.swarm, core.settings.agents
        self.mission_file = mission_file
        self.journal = None if mission_file is None else mission_file.with_name(STEERING_JOURNAL)
        self.script = None if mission_file is None else mission_file.with_name(SCRIPT_FILE)
        self._delete = zenoh.SampleKind.DELETE
        # Liveliness changes must never be dropped (FIFO); poses and agent states are
        # "latest wins" and drained every tick, so a ring that overwrites is right.
        ring = max(1024, 8 * n)
        self._token = session.liveliness().declare_token(alive_key(swarm, "coordinator", 0))
        self._alive = session.liveliness().declare_subscriber(
            alive_selector(swarm), zenoh.handlers.FifoChannel(max(1024, 4 * n)), history=True
        )
        self._poses = session.declare_subscriber(
            all_poses_selector(swarm), zenoh.handlers.RingChannel(ring)
        )
        self._states = session.declare_subscriber(
            all_agent_states_selector(swarm), zenoh.handlers.RingChannel(ring)
        )
        self._domain = session.declare_publisher(domain_key(swarm))
        # Our own Domains come back on it (the core recognises them); any other is a second
        # coordinator's or a forger's.
        self._heard = session.declare_subscriber(
            domain_key(swarm), zenoh.handlers.RingChannel(ring)
        )
        # Steering requests (coordinator.steering): drained every tick, so a request is
        # answered and acted on within one broadcast period.
        self._steer = session.declare_queryable(
            steer_key(swarm), zenoh.handlers.FifoChannel(STEER_QUEUE)
        )
        self._status = session.declare_publisher(status_key(swarm))
        self._world = session.declare_publisher(world_key(swarm))
        # The map's picture, asked for by consoles once per World (a few queries a run);
        # built now, not on the tick of the first query (a large map takes a moment).
        _ = core.map_payload
        self._map = session.declare_queryable(
            world_map_key(swarm), zenoh.handlers.FifoChannel(MAP_QUEUE)
        )

    def receive(self, now: float) -> None:
        """Hand everything that arrived since the last tick to the core; answer steering."""
        core, wall = self.core, time.time()
        while (sample := self._alive.try_recv()) is not None:
            core.on_liveliness(str(sample.key_expr), sample.kind != self._delete, now, wall)
        # 20 000 poses a second at 1000 robots: the loop does no more than take them out.
        received, take = [], self._poses.try_recv
        while (sample := take()) is not None:
            received.append((str(sample.key_expr), sample.payload.to_bytes()))
        core.on_poses(received)
        while (sample := self._states.try_recv()) is not None:
            core.on_agent_state(str(sample.key_expr), sample.payload.to_bytes())
        while (sample := self._heard.try_recv()) is not None:
            core.on_domain_heard(sample.payload.to_bytes())
        while (query := self._steer.try_recv()) is not None:
            payload = b"" if query.payload is None else query.payload.to_bytes()
            requester = requester_key(query.source_info)
            for action in core.on_steer(payload, now, time.time(), requester):
                if isinstance(action, ReplySteer):
                    query.reply(query.key_expr, action.payload)
                    query.drop()  # the final answer: the client stops waiting
                else:
                    self.carry_out(action)
        while (query := self._map.try_recv()) is not None:
            payload = core.map_payload
            if payload is None:  # an answer all the same: the console need not ask again
                query.reply_err(b"no map")
            else:
                query.reply(query.key_expr, payload)
            query.drop()

    def carry_out(self, action: Action) -> None:
        """Do what the core asked (see coordinator.core's actions); Finished is the loop's."""
        if isinstance(action, PublishDomain):
            self._domain.put(action.domain.encode())
        elif isinstance(action, PublishWorld):
            self._world.put(action.world.encode())
        elif isinstance(action, PublishStatus):
            self._status.put(action.status.encode())
        elif isinstance(action, JournalSteering):
            if self.journal is not None:
                with self.journal.open("a", encoding="utf-8") as journal:
                    journal.write(action.line + "\n")
        elif isinstance(action, MissionStarted):
            if self.mission_file is not None:
                mission = {"swarm": action.swarm, "started_wall": action.started_wall}
                self.mission_file.parent.mkdir(parents=True, exist_ok=True)
                self.mission_file.write_text(json.dumps(mission) + "\n", encoding="utf-8")
                self.journal.unlink(missing_ok=True)  # a previous mission's requests
                self.script.unlink(missing_ok=True)  # and script clock
        elif isinstance(action, RecordScriptClock):
            if self.script is not None:
                # Replaced whole (a rename), never left half-written by a crash.
                part = self.script.with_name(self.script.name + ".part")
                part.write_text(action.clock.to_json(action.swarm) + "\n", encoding="utf-8")
                part.replace(self.script)
        elif not isinstance(action, Finished):
            raise TypeError(f"unknown action {action!r}")

    def run(self, stop: StopFlag) -> None:
        """Broadcast until the mission is done (or ``stop`` is set)."""
        settings = self.core.settings
        ticker = Ticker(settings.rate, time_scale=settings.time_scale)
        log.info("waiting for %d agents and %d robots", settings.agents, settings.agents)
        while True:
            now = ticker.wait(stop)
            self.receive(now)
            actions = self.core.tick(now, time.time(), stopping=stop.is_set())
            for action in actions:
                self.carry_out(action)
            if any(isinstance(action, Finished) for action in actions):
                log.info("%d overrun ticks", ticker.overruns)
                return
