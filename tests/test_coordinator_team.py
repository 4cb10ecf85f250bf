"""coordinator.team: phantom ids never enter the records as team members (issue 21)."""

from __future__ import annotations

import numpy as np
import pytest

from covswarm.coordinator.monitor import ErrorRecord, Liveness, losses_summary
from covswarm.coordinator.team import MAX_TRACKED_IDS, REPORTED_IDS, Roster

WALL = 1.7e9


def feed_tokens(roster: Roster, liveness: Liveness, changes: list[tuple[str, int, bool]]) -> None:
    """What the coordinator core does per liveliness sample: the roster first."""
    for role, rid, alive in changes:
        if roster.admit_token(role, rid):
            liveness.update(role, rid, alive, WALL, 1.0)


def test_a_fake_team_member_is_counted_not_recorded() -> None:
    roster, liveness = Roster.of_size(6), Liveness()
    feed_tokens(roster, liveness, [(r, i, True) for i in range(6) for r in ("agent", "robot")])
    # The probe: a token and poses for id 40, then 2930 phantom ids that come and go.
    feed_tokens(roster, liveness, [("agent", 40, True), ("robot", 40, True)])
    phantoms = range(100, 3030)
    feed_tokens(roster, liveness, [("robot", i, True) for i in phantoms])
    feed_tokens(roster, liveness, [("robot", i, False) for i in phantoms])
    assert liveness.count("agent") == 6 and liveness.count("robot") == 6  # status 6/6, not 7/7
    assert roster.members(liveness.alive) == frozenset(range(6))
    assert losses_summary(liveness.events) == []  # no phantom in lost_processes
    record = ErrorRecord()
    poses = {i: (0.1 * i, 0.0) for i in [*range(6), 40, *phantoms]}
    record.add(0.0, 0.0, {i: xy for i, xy in poses.items() if roster.admit_pose(i)}, np.eye(3))
    assert record.robot_ids() == list(range(6))  # trajectories: the team only
    summary = roster.summary()
    assert summary["counts"] == {"token_agent": 1, "token_robot": 1 + 2 * 2930, "pose": 2931}
    assert summary["distinct_ids"] == 2931 and summary["first_ids"][:2] == [40, 100]
    assert len(summary["first_ids"]) == REPORTED_IDS
    # A real member leaving is still a lost process.
    feed_tokens(roster, liveness, [("agent", 3, False)])
    assert [e["id"] for e in losses_summary(liveness.events)] == [3]
    assert roster.members(liveness.alive) == frozenset({0, 1, 2, 4, 5})


def test_poses_count_only_once_the_agent_held_a_token() -> None:
    roster = Roster([2, 5])
    assert not roster.admit_pose(2)  # its agent not up yet: no team member
    assert roster.admit_token("agent", 2)
    assert roster.admit_pose(2) and not roster.admit_pose(5) and not roster.admit_pose(9)
    rows = np.array(
        [[2, 0, WALL, 0.0, 0.0, 0.0], [9, 0, WALL, 1.0, 1.0, 0.0], [2, 1, WALL, 1, 2, 0]]
    )
    kept = roster.admit_observations(rows)
    np.testing.assert_array_equal(kept, rows[[0, 2]])
    assert roster.admit_observations(np.zeros((0, 6))).shape == (0, 6)
    assert roster.admit_state(5) and not roster.admit_state(7)
    assert roster.counts["state"] == 1


def test_distinct_ids_are_bounded_and_bad_rosters_refused() -> None:
    roster = Roster.of_size(1)
    for rid in range(1, 3 * MAX_TRACKED_IDS):
        roster.admit_pose(rid)
    summary = roster.summary()
    assert summary["distinct_ids"] == MAX_TRACKED_IDS and summary["distinct_ids_at_least"]
    assert summary["counts"]["pose"] == 3 * MAX_TRACKED_IDS - 1
    with pytest.raises(ValueError, match="Roster"):
        Roster([])
    with pytest.raises(ValueError, match="Roster"):
        Roster.of_size(0)


def test_a_newcomer_is_admitted_once_its_tokens_are_held_and_the_team_names_it() -> None:
    """A robot joining under an id beyond the team (``covswarm robot`` and ``covswarm
    agent`` started by hand) becomes a member when both its tokens are held and an agent
    of the team names it as a neighbour; tokens, poses and its own states alone do not."""
    roster, liveness = Roster.of_size(2), Liveness()
    feed_tokens(roster, liveness, [(r, i, True) for i in range(2) for r in ("agent", "robot")])
    assert not roster.admit_token("robot", 7) and not roster.admit_state(7)
    roster.vouch(0, [1, 7])  # named, but its agent holds no token yet
    assert not roster.take_admitted() and not roster.admit_pose(7)
    assert not roster.admit_token("robot", 8) and not roster.admit_token("agent", 8)
    roster.vouch(8, [8])  # a phantom vouching for itself
    roster.vouch(9, [8])  # or for another, from an id that is no member
    assert not roster.take_admitted()
    assert not roster.admit_token("agent", 7)  # both tokens, and named before: admitted
    admitted = roster.take_admitted()
    assert sorted(admitted) == [("agent", 7), ("robot", 7)] and not roster.take_admitted()
    for role, rid in admitted:
        liveness.update(role, rid, True, WALL, 1.0)
    assert roster.members(liveness.alive) == frozenset({0, 1, 7})
    assert roster.admit_pose(7) and roster.admit_state(7) and roster.admit_token("robot", 7)
    summary = roster.summary()
    assert summary["first_ids"] == [8]
    assert summary["counts"] == {"token_agent": 1, "token_robot": 1, "pose": 1}
    # A member once, it is one for good: its robot's loss is a lost process.
    feed_tokens(roster, liveness, [("robot", 7, False)])
    assert [e["id"] for e in losses_summary(liveness.events)] == [7]
