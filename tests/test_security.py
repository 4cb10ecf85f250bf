"""Secured mode on loopback: mutual-TLS router; who may join and who may not.

What each role may do once joined is tested in tests/test_secure_roles.py."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from live_runs import alive_tokens, open_router, split_packing_team

from covswarm import protocol
from covswarm.deploy.plan import BRAIN_TICK
from covswarm.protocol.security import make_test_credentials, read_identities
from covswarm.protocol.session import session_config

zenoh = pytest.importorskip("zenoh")


REPO = Path(__file__).resolve().parent.parent
COVSWARM = str(Path(sys.executable).with_name("covswarm"))


@pytest.fixture(scope="module")
def secure(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A fresh CA and certificates for every role, ids 0-15 (one per test module and run)."""
    return make_test_credentials(tmp_path_factory.mktemp("secure"))


@pytest.fixture
def router(secure: Path) -> Iterator[tuple[zenoh.Session, str]]:
    """A secured router-mode session on a free loopback port: (session, tls endpoint)."""
    session, endpoint = open_router("tls", secure)
    yield session, endpoint
    session.close()


def test_secure_folder_is_complete_and_private(secure: Path) -> None:
    names = {entry["name"] for entry in read_identities(secure)}
    assert {"coordinator", "bridge", "console", "operator", "agent-15", "robot-0"} <= names
    assert len(names) == 5 + 2 * 16
    for name in [*names, "router"]:
        assert {p.name for p in (secure / name).iterdir()} == {"cert.pem", "key.pem"}
        assert (secure / name / "key.pem").stat().st_mode & 0o077 == 0
    assert (secure / "ca" / "ca.key").stat().st_mode & 0o077 == 0


def test_secured_mode_refuses_clear_endpoints_and_incomplete_folders(
    secure: Path, tmp_path: Path
) -> None:
    with pytest.raises(ValueError, match="needs tls/ endpoints"):
        session_config(["tcp/127.0.0.1:7447"], secure=secure)
    with pytest.raises(ValueError, match="lacks operator: covswarm credentials"):
        session_config(["tls/127.0.0.1:7447"], secure=tmp_path)  # no CA yet: issue one here
    (tmp_path / "ca.pem").write_text("")
    with pytest.raises(ValueError, match="lacks router/cert.pem, router/key.pem, identities"):
        session_config(None, ["tls/127.0.0.1:7447"], "router", secure=tmp_path)
    shutil.copytree(secure / "router", tmp_path / "router")
    (tmp_path / "identities.json").write_text('[{"name": "agent-1", "role": "agent"}]')
    with pytest.raises(ValueError, match="needs an id"):
        session_config(None, ["tls/127.0.0.1:7447"], "router", secure=tmp_path)
    # A robot's machine (ca.pem and its own folder, no CA key): told to issue it where the
    # CA's key is, not here, where covswarm credentials cannot.
    machine = tmp_path / "machine"
    machine.mkdir()
    shutil.copy(secure / "ca.pem", machine / "ca.pem")
    shutil.copytree(secure / "robot-3", machine / "robot-3")
    with pytest.raises(ValueError, match="lacks robot-5: on the machine that holds") as there:
        session_config(["tls/127.0.0.1:7447"], secure=machine, role="robot", id=5)
    assert "--robot-ids 5, then copy robot-5/ into" in str(there.value)
    # One identity's folder given for the secure folder: pointed at its parent, not told
    # to issue a new CA there.
    with pytest.raises(ValueError, match="not a secure folder") as wrong:
        session_config(["tls/127.0.0.1:7447"], secure=secure / "operator")
    assert f"--secure {secure}" in str(wrong.value) and "covswarm credentials" not in str(
        wrong.value
    )


@pytest.mark.timeout(120)
@pytest.mark.e2e
def test_only_clients_with_credentials_join(router: tuple, secure: Path, tmp_path: Path) -> None:
    session, endpoint = router
    key = f"covswarm/{protocol.new_swarm_name()}/status"
    received: list[bytes] = []
    session.declare_subscriber(key, lambda sample: received.append(sample.payload.to_bytes()))

    with zenoh.open(session_config([endpoint], secure=secure, role="coordinator")) as member:
        member.put(key, b"from a member")
        deadline = time.monotonic() + 10.0
        while not received and time.monotonic() < deadline:
            time.sleep(0.05)
    assert received == [b"from a member"]

    other_lab = make_test_credentials(tmp_path / "other-lab", ids=[0])  # another CA
    with pytest.raises(ValueError, match="a tls/ endpoint needs --secure DIR"):
        session_config([endpoint])  # covswarm refuses it before zenoh; the router must too:
    no_credentials = session_config([endpoint.replace("tls/", "tcp/")])
    no_credentials.insert_json5("connect/endpoints", json.dumps([endpoint]))
    no_credentials.insert_json5(  # TLS with the right CA, but no certificate
        "transport/link/tls/root_ca_certificate", json.dumps(str(secure / "ca.pem"))
    )
    plain_tcp = session_config([endpoint.replace("tls/", "tcp/")])  # no TLS at all
    outsiders = {
        "another CA's certificate": session_config([endpoint], secure=other_lab),
        "no certificate": no_credentials,
        "plain tcp": plain_tcp,
    }
    for name, config in outsiders.items():
        with pytest.raises(zenoh.ZError, match="Unable to connect"):
            zenoh.open(config).close()
            pytest.fail(f"{name}: connected")
    assert received == [b"from a member"]  # nothing else got through


@pytest.mark.e2e
@pytest.mark.timeout(180)
def test_robot_process_joins_a_secured_swarm_with_one_flag(router: tuple, secure: Path) -> None:
    session, endpoint = router
    swarm = protocol.new_swarm_name()
    common = ["--id", "2", "--connect", endpoint, "--swarm", swarm, "--secure", str(secure)]
    child = subprocess.Popen([COVSWARM, "robot", *common], cwd=REPO)
    try:
        alive = protocol.alive_key(swarm, "robot", 2)
        deadline = time.monotonic() + 120.0
        while not alive_tokens(session, alive):
            assert child.poll() is None, "the secured robot exited"
            assert time.monotonic() < deadline, "the secured robot did not come up"
            time.sleep(0.2)
        refused = subprocess.run(
            [COVSWARM, "robot", *common[:-2]], cwd=REPO, capture_output=True, text=True, timeout=120
        )
        assert refused.returncode == 2  # without --secure: refused before any session
        assert "a tls/ endpoint needs --secure DIR" in refused.stderr
    finally:
        child.terminate()
        child.wait(timeout=30)


@pytest.mark.e2e
@pytest.mark.timeout(300)
def test_covswarm_run_is_secured_with_one_flag(secure: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    argv = [COVSWARM, "run", "--secure", str(secure), "--scenario", "circle", "--agents", "2"]
    argv += ["--duration", "2", "--out", str(out)]
    run = subprocess.run(argv, cwd=REPO, capture_output=True, text=True, timeout=280)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    launch = json.loads((out / "launch.json").read_text())
    assert launch["endpoint"].startswith("tls/127.0.0.1:")
    for child in launch["argv"]:
        assert child[child.index("--secure") + 1] == str(secure)
    team = json.loads((out / "summary.json").read_text())["agent_stats"]["team"]
    assert team["drop_undecodable"]["max"] == 0  # drops reach summary.json, per reason


@pytest.mark.e2e
@pytest.mark.timeout(300)
def test_an_auto_packed_secure_run_presents_exactly_its_group_certificates(tmp_path: Path) -> None:
    """``covswarm run --secure`` under auto packing, pinned to one core: a small team whose
    brains go in smaller processes than its robots (live_runs.split_packing_team). Without
    their group certificates the launcher exits 2 naming the command that issues them; that
    command issues each process's certificate and no other, and then the run completes with
    every robot and brain of the packed processes joined on its own certificate."""
    agents, rate = split_packing_team(cores=1)
    folder = make_test_credentials(tmp_path / "secure", ids=[])
    out = tmp_path / "run"
    argv = [COVSWARM, "run", "--secure", str(folder), "--agents", str(agents), "--rate", str(rate)]
    # The brain-tick split_packing_team planned with, not this host's (deploy.host_speed).
    argv += ["--duration", "2", "--out", str(out), "--brain-tick", str(BRAIN_TICK)]

    def one_core() -> None:  # in the launcher before exec: it and its children on one core
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})

    refused = subprocess.run(
        argv, cwd=REPO, capture_output=True, text=True, timeout=60, preexec_fn=one_core
    )
    assert refused.returncode == 2, refused.stdout[-2000:] + refused.stderr[-2000:]
    command = refused.stderr.strip().rpartition(": ")[2].split()
    assert command[:3] == ["covswarm", "credentials", str(folder)], refused.stderr
    subprocess.run([COVSWARM, *command[1:]], check=True, capture_output=True, timeout=120)
    run = subprocess.run(
        argv, cwd=REPO, capture_output=True, text=True, timeout=280, preexec_fn=one_core
    )
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    launch = json.loads((out / "launch.json").read_text())
    assert 1 < launch["agents_per_process"] < launch["robots_per_process"] == agents
    presented = {
        f"{child[2]}-{child[child.index('--ids') + 1]}"
        for child in launch["argv"]
        if child[2] in ("agent", "robot")
    }
    issued = {e["name"] for e in read_identities(folder) if e["role"] in ("agent", "robot")}
    assert issued == presented
    alive = json.loads((out / "summary.json").read_text())["alive_at_end"]
    assert alive == {"agents": agents, "robots": agents}
