"""The covswarm wire protocol: key expressions, message types, session configuration.

Import-light on purpose (msgpack only): robot processes import this module at start-up.
``session_config`` lives in :mod:`protocol.session` (it imports zenoh) and is re-exported
lazily.
"""

from __future__ import annotations

from typing import Any

from covswarm.protocol.keys import (
    MAX_ID,
    PREFIX,
    ROLES,
    KeyIds,
    agent_state_key,
    alive_key,
    alive_selector,
    all_agent_states_selector,
    all_cmds_selector,
    all_poses_selector,
    beacon_key,
    beacon_tile_selector,
    check_id,
    check_swarm,
    claim_key,
    claim_selector,
    cmd_key,
    domain_key,
    new_swarm_name,
    parse_alive_key,
    parse_id,
    pose_key,
    status_key,
    steer_key,
    tile_of,
    world_key,
    world_map_key,
)
from covswarm.protocol.messages import (
    DEFAULT_TILE_SIZE,
    MAX_COORD,
    MAX_OBSTACLE_VERTICES,
    MAX_OBSTACLES,
    MAX_PAYLOAD,
    MAX_RELAY,
    MAX_SPEED,
    MAX_VERTICES,
    MAX_WORLD_PAYLOAD,
    REASONS,
    SCHEMA_VERSION,
    STATES,
    AgentState,
    Beacon,
    Domain,
    MapImage,
    Message,
    Pose,
    ProtocolError,
    Status,
    WheelCommand,
    World,
)

__all__ = [
    "DEFAULT_TILE_SIZE",
    "MAX_COORD",
    "MAX_ID",
    "MAX_PAYLOAD",
    "MAX_RELAY",
    "MAX_OBSTACLES",
    "MAX_OBSTACLE_VERTICES",
    "MAX_SPEED",
    "MAX_VERTICES",
    "MAX_WORLD_PAYLOAD",
    "PREFIX",
    "REASONS",
    "ROLES",
    "SCHEMA_VERSION",
    "STATES",
    "AgentState",
    "Beacon",
    "Domain",
    "MapImage",
    "Message",
    "Pose",
    "ProtocolError",
    "Status",
    "WheelCommand",
    "World",
    "agent_state_key",
    "alive_key",
    "alive_selector",
    "all_agent_states_selector",
    "all_cmds_selector",
    "all_poses_selector",
    "beacon_key",
    "beacon_tile_selector",
    "check_id",
    "check_swarm",
    "claim_key",
    "claim_selector",
    "cmd_key",
    "domain_key",
    "new_swarm_name",
    "parse_alive_key",
    "KeyIds",
    "parse_id",
    "pose_key",
    "session_config",
    "status_key",
    "steer_key",
    "tile_of",
    "world_key",
    "world_map_key",
]


def __getattr__(name: str) -> Any:
    # Lazy so that importing the protocol does not import zenoh (tests, offline tools).
    if name == "session_config":
        from covswarm.protocol.session import session_config

        return session_config
    raise AttributeError(f"module 'protocol' has no attribute {name!r}")
