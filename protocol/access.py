"""The router's access-control list in secured mode: least privilege by role and id.

Zenoh's access control (``access_control`` in the router's config) matches a remote
session to *subjects* by the common name of its client certificate (mutual TLS), and
applies the *rules* its *policies* bind to it; anything no rule allows is denied
(``default_permission: deny``). Here:

- everyone may subscribe, query liveliness and receive everything under ``covswarm/``
  (reading is not restricted: a certificate already keeps outsiders out);
- only ``agent-i`` may put ``robot/i/cmd``, ``agent/i/state``, its beacons and hold the
  tokens ``alive/agent/i`` and ``claim/agent/i/*`` (an agent process running several
  brains holds one certificate for all its ids);
- only ``robot-i`` (or the ``bridge``, which speaks for every real robot) may put
  ``robot/i/pose`` and hold ``alive/robot/i`` and ``claim/robot/i/*``;
- only the ``coordinator`` may put the Domain and the Status, hold its tokens, declare the
  ``steer`` queryable, receive the queries and reply;
- the ``operator`` and the ``console`` (and the coordinator) may query ``steer``;
- another host's router (``--router-connect``; common name ``router``) relays everything:
  each router enforces the rules on its own clients, so what reaches a router from
  another has already been checked at its entry;
- the ``bridge`` also speaks ROS 2 (rmw_zenoh) on the same session: everything under the
  ROS 2 keys (``<domain id>/**``, ``@ros2_lv/**``), none of which is under ``covswarm/``;
  so may ROS 2 nodes on the same router (certificate ``ros2``), and nothing else.

Message kinds are Zenoh's: ingress is what the router accepts from the subject, egress what
it forwards to it. Pure data, no zenoh import: the dict goes into the config as JSON.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

SWARM = "covswarm/*"  # every swarm name: one certificate serves any run of the lab
READ = "read"
ROS2_DOMAINS = range(233)  # ROS 2 domain ids 0..232 (bridge.rmw_zenoh.MAX_DOMAIN_ID)
ALL_MESSAGES = (
    "put",
    "delete",
    "query",
    "reply",
    "declare_subscriber",
    "declare_queryable",
    "liveliness_token",
    "declare_liveliness_subscriber",
    "liveliness_query",
)
# A reader may do everything but send queries.
READ_MESSAGES = tuple(message for message in ALL_MESSAGES if message != "query")


def _rule(rule_id: str, flows: Sequence[str], messages: Sequence[str], keys: Sequence[str]):
    return {
        "id": rule_id,
        "permission": "allow",
        "flows": list(flows),
        "messages": list(messages),
        "key_exprs": list(keys),
    }


def agent_keys(ids: Sequence[int]) -> tuple[list[str], list[str]]:
    """(keys agent ``ids`` may put, liveliness tokens they may hold)."""
    puts = [f"{SWARM}/robot/{i}/cmd" for i in ids]
    puts += [f"{SWARM}/agent/{i}/state" for i in ids]
    puts += [f"{SWARM}/beacon/*/*/{i}" for i in ids]
    tokens = [f"{SWARM}/alive/agent/{i}" for i in ids]
    tokens += [f"{SWARM}/claim/agent/{i}/*" for i in ids]
    return puts, tokens


def robot_keys(ids: Sequence[int] | None) -> tuple[list[str], list[str]]:
    """(keys robots ``ids`` may put, tokens they may hold); None: every robot (bridge)."""
    chunks = ["*"] if ids is None else [str(i) for i in ids]
    puts = [f"{SWARM}/robot/{i}/pose" for i in chunks]
    tokens = [f"{SWARM}/alive/robot/{i}" for i in chunks]
    tokens += [f"{SWARM}/claim/robot/{i}/*" for i in chunks]
    return puts, tokens


def _writer(rule_id: str, puts: list[str], tokens: list[str]) -> list[dict[str, Any]]:
    return [
        _rule(f"{rule_id}/put", ["ingress"], ["put", "delete"], puts),
        _rule(f"{rule_id}/token", ["ingress"], ["liveliness_token"], tokens),
    ]


def access_control(identities: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The ``access_control`` config for ``identities`` (name, role, ids; see
    protocol.security.read_identities): a subject, its rules and a policy per identity.

    Rules are per identity (N agents: N subjects and N policies); the router's cost of
    that is measured in docs/security.md.
    """
    steer, world_map = f"{SWARM}/steer", f"{SWARM}/world/map"
    rules = [
        _rule(READ, ["egress"], READ_MESSAGES, [f"{SWARM}/**"]),
        _rule(
            "subscribe",
            ["ingress"],
            ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"],
            [f"{SWARM}/**"],
        ),
        _rule("steer/ask", ["ingress"], ["query"], [steer]),
        _rule("steer/answer", ["ingress"], ["declare_queryable", "reply"], [steer]),
        _rule("steer/serve", ["egress"], ["query"], [steer]),
        # The map's picture (protocol.MapImage): asked by consoles, answered by the coordinator.
        _rule("map/ask", ["ingress"], ["query"], [world_map]),
        _rule("map/answer", ["ingress"], ["declare_queryable", "reply"], [world_map]),
        _rule("map/serve", ["egress"], ["query"], [world_map]),
    ]
    coordinator = _writer(
        "coordinator",
        [f"{SWARM}/domain", f"{SWARM}/status", f"{SWARM}/world"],
        [f"{SWARM}/alive/coordinator/0", f"{SWARM}/claim/coordinator/0/*"],
    )
    ros2 = ["@ros2_lv/**", *(f"{domain}/**" for domain in ROS2_DOMAINS)]
    bridge = [
        *_writer("bridge", *robot_keys(None)),
    ]
    rules.append(_rule("ros2", ["ingress", "egress"], ALL_MESSAGES, ros2))
    rules += coordinator + bridge
    base = [READ, "subscribe"]
    by_role = {
        "coordinator": [
            *base,
            "steer/ask",
            "steer/answer",
            "steer/serve",
            "map/answer",
            "map/serve",
        ]
        + [r["id"] for r in coordinator],
        "bridge": [*base, "ros2"] + [r["id"] for r in bridge],
        "ros2": ["ros2"],  # ROS 2 nodes: their own keys only, nothing of covswarm
        "console": [*base, "steer/ask", "map/ask"],
        "operator": [*base, "steer/ask", "map/ask"],
    }
    rules.append(_rule("relay", ["ingress", "egress"], ALL_MESSAGES, ["**"]))
    subjects = [{"id": "router", "cert_common_names": ["router"]}]
    policies = [{"id": "router", "rules": ["relay"], "subjects": ["router"]}]
    for identity in identities:
        name, role, ids = identity["name"], identity["role"], list(identity.get("ids") or [])
        if role == "agent":
            own = _writer(name, *agent_keys(ids))
        elif role == "robot":
            own = _writer(name, *robot_keys(ids))
        else:
            own = []
        rules += own
        subjects.append({"id": name, "cert_common_names": [name]})
        policies.append(
            {"id": name, "rules": by_role.get(role, base) + [r["id"] for r in own],
             "subjects": [name]}
        )  # fmt: skip
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }
