"""A brain's receive path: a turn's payloads in one call (AgentBrain.receive_all, what a
packed brain does) against the same payloads one by one, and against a reference that
applies each message through the brain's public handlers, the receive path as specified
(module notes of covswarm.agent.brain and covswarm.agent.latency)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from wire_samples import domain_message

from covswarm import protocol
from covswarm.agent.brain import MAX_PREDICTION, AgentBrain, AgentConfig
from covswarm.agent.decoding import MESSAGE_TYPES
from covswarm.agent.latency import ClockBound
from covswarm.protocol.inbound import check_stamp

WALL = 1.7e9
ME = 0
OTHERS = (1, 2, 3, 4, 5)
SQUARE = [[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]]
# s relative to our wall clock: fresh, slightly ahead (within the skew), a sender ahead of
# us by more than the skew, older than the staleness timeout, older than the beacons'
STAMP_OFFSETS = (0.0, -0.03, -0.2, 0.3, 0.8, -1.2, -30.0)


def reference_receive(
    brain: AgentBrain, kind: str, payload: bytes, now: float, wall: float, key_id: int | None
) -> bool:
    """One payload as the brain must take it: decoded and validated, its stamp checked
    (covswarm.protocol.inbound), its key's id matched, its sender's clock bounded (a state
    dead-reckoned from its stamp on our clock, a beacon dated by it), then handed to the
    handler of its kind."""
    brain.counters.received += 1
    max_age = brain.config.beacon_timeout if kind == "beacon" else brain.config.stale_timeout
    try:
        message = MESSAGE_TYPES[kind].decode(payload)
        check_stamp(message.stamp, wall, max_age, brain.config.max_clock_skew)
    except protocol.ProtocolError as exc:
        brain.drops.drop(exc.reason, "reference")
        return False
    if key_id is not None and message.id != key_id:
        brain.drops.drop("wrong_id", "reference")
        return False
    if kind == "pose" and message.id == brain.id:
        brain.robot_clock.add(now, wall, message.stamp)
    elif kind == "state":
        clock = brain.peer_clocks.setdefault(message.id, ClockBound())
        clock.add(now, wall, message.stamp)
        now -= min(max(wall - clock.to_local(message.stamp), 0.0), MAX_PREDICTION)
    elif kind == "beacon":  # dated back likewise, by its sender's bound when there is one
        clock = brain.peer_clocks.get(message.id)
        local = message.stamp if clock is None else clock.to_local(message.stamp)
        now -= min(max(wall - local, 0.0), MAX_PREDICTION)
    handler = {
        "pose": brain.on_pose,
        "state": brain.on_agent_state,
        "beacon": brain.on_beacon,
        "domain": brain.on_domain,
    }[kind]
    accepted = handler(message, now)  # type: ignore[operator]
    if accepted and kind == "domain":
        brain.coordinator_clock.add(now, wall, message.stamp)
    return accepted


def random_items(
    rng: np.random.Generator, wall: float, seq: int
) -> list[tuple[str, int | None, bytes]]:
    """A turn's worth of payloads, valid and adversarial, in a random order: runs of
    states broken by the other kinds, own and others' ids, keys that disagree with the
    message, stamps out of policy, junk, a payload of another kind."""
    items: list[tuple[str, int | None, bytes]] = []
    for _ in range(int(rng.integers(1, 16))):
        kind = str(rng.choice(["state", "state", "state", "pose", "beacon", "domain", "junk"]))
        rid = int(rng.choice((ME, *OTHERS)))
        stamp = wall + float(rng.choice(STAMP_OFFSETS))
        x, y = (float(v) for v in rng.uniform(0.1, 1.9, 2))
        key_id: int | None = rid if rng.random() < 0.9 else int(rng.choice(OTHERS))
        if kind == "state":
            others = [r for r in (ME, *OTHERS) if r != rid]
            neighbors = [int(r) for r in rng.choice(others, int(rng.integers(0, 4)), replace=False)]
            moving = rng.random() < 0.7
            relay = None
            if rng.random() < 0.5:
                relay = [
                    (r, *(float(v) for v in rng.uniform(0.1, 1.9, 2)), 0.01, 0.0) for r in neighbors
                ]
            payload = protocol.AgentState(
                id=rid, x=x, y=y, stamp=stamp, neighbors=neighbors,
                vx=float(rng.uniform(-0.1, 0.1)) if moving else None,
                vy=float(rng.uniform(-0.1, 0.1)) if moving else None,
                relay=relay,
            ).encode()  # fmt: skip
        elif kind == "pose":
            payload = protocol.Pose(id=rid, x=x, y=y, theta=0.0, stamp=stamp, seq=seq).encode()
        elif kind == "beacon":
            payload = protocol.Beacon(id=rid, x=x, y=y, stamp=stamp).encode()
        elif kind == "domain":
            seq += int(rng.choice([1, 1, 0, -1, 5000]))
            payload = domain_message(SQUARE, seq=max(seq, 0), stamp=stamp).encode()
            key_id = None
        else:  # junk, or a valid payload of another kind
            kind = str(rng.choice(["state", "pose", "beacon"]))
            payload = (
                b"\x93junk"
                if rng.random() < 0.5
                else protocol.Beacon(id=rid, x=x, y=y, stamp=stamp).encode()
            )
            if kind == "beacon":
                payload = b"\x81\xa1v\x01"  # a map without the fields
        items.append((kind, key_id, payload))
    return items


def snapshot(brain: AgentBrain) -> str:
    """Everything the receive path writes, as text (NaN bounds compare equal so)."""
    nb = brain.neighborhood
    ledger = nb._ledger
    beacons = {rid: (t.x, t.y, t.received) for rid, t in nb.beacons.items()}
    return repr(
        (
            vars(brain.counters),
            brain.drops.counts,
            nb.poses,
            nb.states,
            beacons,
            nb.relays,
            nb._heard,
            nb.asked,
            nb._revived,
            ledger.heard[: ledger.n].tolist(),
            None if nb._choice is None else nb._choice.current,
            {rid: clock._samples for rid, clock in brain.peer_clocks.items()},
            brain.robot_clock._samples,
            brain.coordinator_clock._samples,
            brain.pose,
            brain.pose_received,
            brain.pose_taken,
            brain.domain,
        )
    )


@pytest.mark.parametrize("seed", range(6))
def test_receive_all_is_receive_one_by_one_and_the_reference(seed: int) -> None:
    """Random adversarial turns: the brain that takes each turn in one call, the one that
    takes it payload by payload and the reference accept, drop (by reason) and record
    exactly the same, and then step alike; liveliness changes between turns (revivals)."""
    rng = np.random.default_rng(seed)
    config = AgentConfig(beacon_timeout=5.0)
    brains = [AgentBrain(ME, config, clock=lambda: 0.0) for _ in range(3)]
    batched, single, reference = brains
    seq, accepted = 0, 0
    for turn in range(40):
        now, wall = 0.1 * turn, WALL + 0.1 * turn
        items = random_items(rng, wall, seq)
        seq += 1
        count = batched.receive_all(items, now, wall)
        ones = [single.receive(kind, payload, now, wall, key_id) for kind, key_id, payload in items]
        refs = [
            reference_receive(reference, kind, p, now, wall, key_id) for kind, key_id, p in items
        ]
        assert count == sum(ones) == sum(refs)
        assert ones == refs
        accepted += count
        assert snapshot(batched) == snapshot(single) == snapshot(reference), turn
        if rng.random() < 0.3:
            change = (
                str(rng.choice(["agent", "robot"])),
                int(rng.choice(OTHERS)),
                rng.random() < 0.5,
            )
            for brain in brains:
                brain.on_liveliness(*change)
        actions = [repr(brain.tick(now, wall)) for brain in brains]
        assert actions[0] == actions[1] == actions[2], turn
    # the lists were adversarial, and yet not all refused
    drops = batched.drops.counts
    assert 0 < accepted < batched.counters.received
    assert all(drops[reason] > 0 for reason in ("stamp_future", "stamp_old", "wrong_id", "schema"))
    assert batched.neighborhood.states and batched.neighborhood.beacons
    assert not math.isnan(batched.robot_clock.bound)
