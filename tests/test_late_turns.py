"""A brain whose turns come late (an overloaded process, covswarm.agent.pack) judges its
neighbours' AgentStates against the pace it is stepped at (AgentBrain.pace): they keep
their place in the local diagram for STALE_TURNS gaps between two of its turns, within
[stale_timeout, STALE_STRETCH x stale_timeout], and at the asked rate nothing changes."""

from __future__ import annotations

import pytest
from wire_samples import domain_message

from covswarm import protocol
from covswarm.agent.brain import STALE_STRETCH, STALE_TURNS, AgentBrain, AgentConfig

WALL = 1.7e9
SQUARE = [[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]]


def running_brain() -> AgentBrain:
    """Brain 0 at (1, 1) with a running domain, at mission time 0."""
    brain = AgentBrain(0, AgentConfig())
    brain.receive("domain", domain_message(SQUARE, seq=1, stamp=WALL).encode(), 0.0, WALL)
    pose = protocol.Pose(id=0, x=1.0, y=1.0, theta=0.0, stamp=WALL, seq=1)
    brain.receive("pose", pose.encode(), 0.0, WALL, key_id=0)
    assert brain.running
    return brain


def neighbour_state(stamp: float) -> bytes:
    return protocol.AgentState(id=1, x=1.3, y=1.0, stamp=stamp, neighbors=(0,)).encode()


@pytest.mark.parametrize(("gap", "kept"), [(0.1, False), (0.5, False), (0.8, True), (1.0, True)])
def test_a_neighbour_stays_a_candidate_for_two_gaps_between_late_turns(
    gap: float, kept: bool
) -> None:
    brain = running_brain()
    assert brain.receive("state", neighbour_state(WALL), 0.0, WALL, key_id=1)
    brain.pace(gap)
    age = 1.5  # older than the stale timeout (1 s), younger than two gaps of 0.8 s
    brain.neighborhood.refresh(age)
    assert (1 in brain.neighborhood.first_hand) is kept
    assert brain.counters.stale_stretched == int(STALE_TURNS * gap > brain.config.stale_timeout)


def test_a_late_turn_takes_a_state_older_than_the_stale_timeout_at_receipt() -> None:
    stamp = WALL - 2.0  # beyond the stale timeout and the clock skew allowed (0.5 s)
    on_time, late = running_brain(), running_brain()
    on_time.pace(0.1)
    late.pace(1.0)
    assert not on_time.receive("state", neighbour_state(stamp), 0.0, WALL, key_id=1)
    assert on_time.drops.counts["stamp_old"] == 1
    assert late.receive("state", neighbour_state(stamp), 0.0, WALL, key_id=1)
    assert late.drops.counts.get("stamp_old", 0) == 0


def test_the_stretch_is_bounded_and_undone_when_turns_come_on_time_again() -> None:
    brain = running_brain()
    stale = brain.config.stale_timeout
    brain.pace(1000.0)  # a process frozen for minutes: at most STALE_STRETCH timeouts
    assert brain.neighborhood.stale_timeout == pytest.approx(STALE_STRETCH * stale)
    assert not brain.receive("state", neighbour_state(WALL - 5.0), 0.0, WALL, key_id=1)
    brain.pace(0.1)
    assert brain.neighborhood.stale_timeout == stale
    assert not brain.receive("state", neighbour_state(WALL - 2.0), 0.0, WALL, key_id=1)
