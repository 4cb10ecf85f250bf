"""Floods cost a count, not the mission (issue 21): a hostile session on a running swarm's
router puts garbage on a robot's command key and on the domain key and floods the steering
service; the mission goes on and summary.json counts what was dropped or refused, and the
coordinator reports that another process publishes on its domain key."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
from live_runs import launch, mission_started, new_swarm

from covswarm import protocol

pytestmark = pytest.mark.e2e


@pytest.mark.timeout(180)
def test_floods_are_counted_in_summary_json_and_the_mission_goes_on(tmp_path: Path) -> None:
    import zenoh

    from covswarm.coordinator.steer_client import SteeringClient

    swarm, out = new_swarm(), tmp_path / "flood"
    # The floods end about 4 s into the mission (30 requests, then 3 s of garbage); the
    # mission goes on 6 s more.
    args = ("--scenario", "live", "--agents", "3", "--duration", "10")
    with launch(out, *args, swarm=swarm) as run:
        endpoint = mission_started(run, out)
        with zenoh.open(protocol.session_config([endpoint])) as hostile:
            client = SteeringClient(hostile, swarm)
            replies = [client.translate(0.0, 0.0, duration=1.0) for _ in range(30)]
            for _ in range(60):  # 3 s at 20 Hz, each burst more than a ring holds
                for _ in range(5):
                    hostile.put(protocol.cmd_key(swarm, 0), b"\xc1garbage")
                    hostile.put(protocol.domain_key(swarm), b"\xc1garbage")
                time.sleep(0.05)
        assert sum(not r.accepted and r.reason.startswith("rate-limited") for r in replies) >= 10
        run.wait(timeout=120)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["robot_drops"]["0"]["undecodable"] >= 50, summary["robot_drops"]
    assert summary["steering_refused"]["rate-limited"] >= 10, summary["steering_refused"]
    domain_drops = summary["agent_stats"]["team"]["drop_undecodable"]["max"]
    assert domain_drops >= 50, summary["agent_stats"]["team"]
    # The coordinator hears the garbage on its domain key too: someone else publishes there.
    assert summary["foreign_domains"] >= 50
    assert summary["lost_processes"] == [] and summary["final_error"] < 0.05
