"""Secured mode, role by role: each process has its own certificate and the router lets it
put, declare and query only what its role and ids may (protocol.access).

The e2e tests run a real router process on loopback with the issued credentials and try
each forgery of issue 21 from a hostile session holding another role's certificate: the
router refuses it, and a legitimate message sent after it arrives (so "nothing received"
is not a dead link).
"""

from __future__ import annotations

import shutil
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from live_runs import split_packing_team, wait_until

from covswarm import protocol
from covswarm.deploy.plan import covswarm_argv
from covswarm.protocol.access import access_control
from covswarm.protocol.security import (
    identity_name,
    issue_credentials,
    read_identities,
    require_identities,
)
from covswarm.protocol.session import session_config

zenoh = pytest.importorskip("zenoh")

ROUTER = """
import signal, sys, zenoh
from pathlib import Path
from covswarm.protocol import session_config
peers = sys.argv[3:]  # other hosts' routers
with zenoh.open(session_config(peers, [sys.argv[1]], mode="router", secure=Path(sys.argv[2]))):
    print("ready", flush=True)
    signal.pause()  # until SIGTERM
"""
AGENTS, ROBOTS = [0, 1, 2], [0, 1, 2, 30]
# Group certificates: for both roles, as --agents-per-process 3 packs; and an agent group
# with a smaller robot group, as auto packing hosts robots in fewer processes than brains.
GROUP, AGENT_GROUP, ROBOT_GROUP = [5, 6, 7], [8, 9, 10], [8, 9]
SETTLE = 0.5  # s for declarations to reach the router before a put or a query


@pytest.fixture(scope="module", autouse=True)
def openssl(require) -> None:
    require(shutil.which("openssl") is not None, "needs openssl (apt-get install openssl)")


@pytest.fixture(scope="module")
def creds(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return issue_credentials(
        tmp_path_factory.mktemp("secure"), agents=AGENTS, robots=ROBOTS, groups=[GROUP],
        agent_groups=[AGENT_GROUP], robot_groups=[ROBOT_GROUP],
    )  # fmt: skip


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextmanager
def secured_router(creds: Path, *peers: str) -> Iterator[str]:
    """A secured router in its own process: its tls endpoint (stopped by pid at the end)."""
    for _ in range(5):  # the port can be taken between probing and binding
        endpoint = f"tls/127.0.0.1:{_free_port()}"
        router = subprocess.Popen(
            [sys.executable, "-c", ROUTER, endpoint, str(creds), *peers],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        if router.stdout.readline().strip() == "ready":
            break
        router.wait(timeout=30)
    else:
        pytest.fail(f"the secured router did not start: {router.stderr.read()[-2000:]}")
    try:
        yield endpoint
    finally:
        router.terminate()
        router.wait(timeout=30)


@pytest.fixture(scope="module")
def endpoint(creds: Path) -> Iterator[str]:
    with secured_router(creds) as endpoint:
        yield endpoint


def join(endpoint: str, creds: Path, role: str, id: int | list[int] | None = None):  # noqa: A002
    return zenoh.open(session_config([endpoint], secure=creds, role=role, id=id))


class Inbox:
    """Samples received by a subscriber: (key, payload) pairs, and a way to wait for one."""

    def __init__(self, session, selector: str) -> None:
        self.items: list[tuple[str, bytes]] = []
        self._arrived = threading.Condition()
        self.subscriber = session.declare_subscriber(selector, self._on)

    def _on(self, sample) -> None:
        with self._arrived:
            self.items.append((str(sample.key_expr), sample.payload.to_bytes()))
            self._arrived.notify_all()

    def wait_for(self, payload: bytes, timeout: float = 5.0) -> bool:
        with self._arrived:
            return self._arrived.wait_for(
                lambda: any(p == payload for _, p in self.items), timeout=timeout
            )


# ---- credentials and the access-control list, without a router ----


def test_credentials_give_each_identity_its_own_certificate(creds: Path) -> None:
    names = {entry["name"] for entry in read_identities(creds)}
    expected = {"coordinator", "bridge", "console", "operator", "ros2", "agent-5-7", "robot-5-7"}
    expected |= {"agent-8-10", "robot-8-9"}
    expected |= {f"agent-{i}" for i in AGENTS} | {f"robot-{i}" for i in ROBOTS}
    assert names == expected
    for name in [*names, "router"]:
        assert (creds / name / "key.pem").stat().st_mode & 0o077 == 0
        subject = subprocess.run(
            ["openssl", "x509", "-noout", "-subject", "-in", str(creds / name / "cert.pem")],
            capture_output=True, text=True, check=True,
        ).stdout  # fmt: skip
        assert subject.strip().endswith(f"CN = {name}"), subject
        verified = subprocess.run(
            ["openssl", "verify", "-CAfile", str(creds / "ca.pem"), str(creds / name / "cert.pem")],
            capture_output=True, text=True,
        )  # fmt: skip
        assert verified.returncode == 0, verified.stderr
    assert (creds / "ca" / "ca.key").stat().st_mode & 0o077 == 0


def test_issuing_again_adds_identities_signed_by_the_same_ca(tmp_path: Path) -> None:
    folder = issue_credentials(tmp_path / "lab", agents=[0], robots=[0], hosts=["10.0.0.7"])
    router = str(folder / "router" / "cert.pem")
    names = subprocess.run(
        ["openssl", "x509", "-noout", "-ext", "subjectAltName", "-in", router],
        capture_output=True, text=True, check=True,
    ).stdout  # fmt: skip
    assert "IP Address:127.0.0.1" in names and "IP Address:10.0.0.7" in names
    assert "DNS:localhost" in names
    with pytest.raises(ValueError, match="invalid router host"):
        issue_credentials(folder, hosts=["bad host;rm"])
    ca, first = (folder / "ca.pem").read_bytes(), (folder / "agent-0" / "cert.pem").read_bytes()
    issue_credentials(folder, agents=[0, 9], robots=[])
    assert (folder / "ca.pem").read_bytes() == ca  # same CA
    assert (folder / "agent-0" / "cert.pem").read_bytes() == first  # kept, not re-issued
    names = [entry["name"] for entry in read_identities(folder)]
    assert sorted(names) == sorted(
        ["coordinator", "bridge", "console", "operator", "ros2", "agent-0", "robot-0", "agent-9"]
    )
    (folder / "ca" / "ca.key").unlink()  # a machine's copy cannot issue
    with pytest.raises(ValueError, match="cannot issue"):
        issue_credentials(folder, agents=[3])


def test_identity_names_and_bad_roles() -> None:
    assert identity_name("agent", 3) == "agent-3"
    assert identity_name("robot", [0, 1, 2, 4]) == "robot-0-2,4"
    assert identity_name("coordinator") == "coordinator"
    bad = [("agent", None), ("operator", 1), ("admin", None), ("robot", []), ("robot", [-1])]
    for role, ids in [*bad, ("agent", True), ("agent", 70000)]:
        with pytest.raises(ValueError):
            identity_name(role, ids)
    with pytest.raises(ValueError, match="needs an id"):
        session_config(["tcp/127.0.0.1:7447"], role="agent")  # caught in open mode too


def test_a_machine_without_its_certificate_is_told_how_to_issue_it(creds: Path) -> None:
    with pytest.raises(ValueError, match=r"lacks agent-9: covswarm credentials .* --agent-ids 9$"):
        session_config(["tls/127.0.0.1:7447"], secure=creds, role="agent", id=9)
    with pytest.raises(ValueError, match=r"lacks agent-0-49: .* --agent-group 0-49$"):
        session_config(["tls/127.0.0.1:7447"], secure=creds, role="agent", id=range(50))


def test_a_launcher_learns_every_missing_identity_at_once(creds: Path) -> None:
    require_identities(creds, ["coordinator", "agent-0", "robot-5-7"])
    wanted = ["agent-0", "agent-11-12", "robot-11-12", "robot-14", "agent-15", "agent-16"]
    wanted += ["robot-16", "agent-17-19", "robot-17-18"]
    with pytest.raises(ValueError) as missing:
        require_identities(creds, wanted)
    assert f"lacks {', '.join(wanted[1:])}" in str(missing.value)
    # Exactly what is missing: an id or group both roles lack in --ids/--group, others in
    # the option of the one role that lacks it.
    assert str(missing.value).endswith(
        f"covswarm credentials {creds} --group 11-12 --robot-group 17-18 --agent-group 17-19"
        " --agent-ids 15-16 --robot-ids 14,16"
    )


def test_an_auto_packed_run_is_told_to_issue_exactly_its_processes_certificates(
    tmp_path: Path,
) -> None:
    """A small team whose auto packing on 2 cores puts brains in smaller processes than
    robots (live_runs.split_packing_team; deploy.plan: robots one process per core, brains
    in batches that hold the rate):
    the command the launcher's check names issues each process's certificate and no other
    group, and each group's certificate may put and hold the keys of its own ids only."""
    from click.testing import CliRunner

    from covswarm.deploy.plan import (
        RunConfig,
        auto_per_process,
        auto_robots_per_process,
        plan_children,
    )
    from covswarm.mission.scenario_files import load_scenario
    from covswarm.protocol.security import credentials_command

    cores = 2
    agents, rate = split_packing_team(cores)
    run = RunConfig(agents=agents, rate=rate, swarm="s", out=tmp_path / "run")
    specs = plan_children(
        run, load_scenario("passage"), endpoint="tcp/127.0.0.1:7447", base=(),
        per_process=auto_per_process(agents, cores, rate),
        robots_per_process=auto_robots_per_process(agents, cores),
    )  # fmt: skip
    names = {spec.identity for spec in specs}
    groups = {spec.identity for spec in specs if spec.role in ("agent", "robot")}
    half = -(-agents // cores)
    robot_groups = {f"robot-0-{half - 1}", f"robot-{half}-{agents - 1}"}
    assert {n for n in groups if n.startswith("robot-")} == robot_groups
    folder = tmp_path / "secure"
    with pytest.raises(ValueError) as missing:
        require_identities(folder, sorted(names))
    command = str(missing.value).rpartition(": ")[2].split()
    assert command[:3] == ["covswarm", "credentials", str(folder)]
    done = CliRunner().invoke(credentials_command, command[2:])
    assert done.exit_code == 0, done.output
    require_identities(folder, sorted(names))
    issued = read_identities(folder)
    assert {e["name"] for e in issued if e["role"] in ("agent", "robot")} == groups
    acl = access_control(issued)
    swarm = protocol.new_swarm_name()
    for spec in specs:
        if spec.role not in ("agent", "robot"):
            continue
        for i in range(agents):
            pose = _allowed(acl, spec.identity, "ingress", "put", protocol.pose_key(swarm, i))
            cmd = _allowed(acl, spec.identity, "ingress", "put", protocol.cmd_key(swarm, i))
            token = protocol.alive_key(swarm, spec.role, i)
            held = _allowed(acl, spec.identity, "ingress", "liveliness_token", token)
            assert (pose, cmd) == (
                spec.role == "robot" and i in spec.members,
                spec.role == "agent" and i in spec.members,
            ), (spec.identity, i)
            assert held == (i in spec.members), (spec.identity, i)


def _allowed(acl: dict, subject: str, flow: str, message: str, key: str) -> bool:
    """Brute-force reading of the list: does any rule of ``subject``'s policy allow it?"""
    rules = {rule["id"]: rule for rule in acl["rules"]}
    [policy] = [p for p in acl["policies"] if subject in p["subjects"]]
    return any(
        flow in rules[r]["flows"]
        and message in rules[r]["messages"]
        and any(zenoh.KeyExpr(k).intersects(zenoh.KeyExpr(key)) for k in rules[r]["key_exprs"])
        for r in policy["rules"]
    )


def test_the_access_list_grants_each_key_to_its_owner_only(creds: Path) -> None:
    acl = access_control(read_identities(creds))
    assert acl["default_permission"] == "deny"
    swarm = protocol.new_swarm_name()
    owners: dict[str, set[str]] = {
        protocol.domain_key(swarm): {"coordinator"},
        protocol.status_key(swarm): {"coordinator"},
        protocol.world_key(swarm): {"coordinator"},
        protocol.world_map_key(swarm): set(),  # a queryable's key: nobody puts there
    }
    ids = range(12)
    for i in ids:
        agent = {identity_name("agent", i)} if i in AGENTS else set()
        robot = {identity_name("robot", i)} if i in ROBOTS else set()
        for group, role, owner in [
            (GROUP, "agent", agent), (GROUP, "robot", robot),
            (AGENT_GROUP, "agent", agent), (ROBOT_GROUP, "robot", robot),
        ]:  # fmt: skip
            if i in group:
                owner.add(identity_name(role, group))
        owners[protocol.cmd_key(swarm, i)] = agent
        owners[protocol.agent_state_key(swarm, i)] = agent
        owners[protocol.beacon_key(swarm, -3, 7, i)] = agent
        owners[protocol.pose_key(swarm, i)] = robot | {"bridge"}
    tokens: dict[str, set[str]] = {protocol.alive_key(swarm, "coordinator", 0): {"coordinator"}}
    for i in ids:
        for role, owner in [("agent", owners[protocol.cmd_key(swarm, i)])]:
            tokens[protocol.alive_key(swarm, role, i)] = owner
            tokens[protocol.claim_key(swarm, role, i, "ab12")] = owner
        robot = owners[protocol.pose_key(swarm, i)]
        tokens[protocol.alive_key(swarm, "robot", i)] = robot
        tokens[protocol.claim_key(swarm, "robot", i, "ab12")] = robot
    subjects = [s["id"] for s in acl["subjects"] if s["id"] not in ("router", "ros2")]
    ros2 = ["0/robot_0/cmd_vel/geometry_msgs::msg::dds_::Twist_/RIHS01_x", "@ros2_lv/0/a"]
    assert _allowed(acl, "router", "ingress", "put", protocol.cmd_key(swarm, 0))  # a relay
    for subject in subjects:
        for key, who in owners.items():
            assert _allowed(acl, subject, "ingress", "put", key) == (subject in who), (subject, key)
            assert _allowed(acl, subject, "egress", "put", key)  # everyone may read
            assert _allowed(acl, subject, "ingress", "declare_subscriber", key)
        for key, who in tokens.items():
            ok = _allowed(acl, subject, "ingress", "liveliness_token", key)
            assert ok == (subject in who), (subject, key)
        steer = protocol.steer_key(swarm)
        assert _allowed(acl, subject, "ingress", "declare_queryable", steer) == (
            subject == "coordinator"
        )
        assert _allowed(acl, subject, "ingress", "query", steer) == (
            subject in ("coordinator", "console", "operator")
        )
        # The map's picture: only the coordinator answers, consoles and operators ask.
        world_map = protocol.world_map_key(swarm)
        for message in ("declare_queryable", "reply"):
            assert _allowed(acl, subject, "ingress", message, world_map) == (
                subject == "coordinator"
            ), (subject, message)
        assert _allowed(acl, subject, "egress", "query", world_map) == (subject == "coordinator")
        assert _allowed(acl, subject, "ingress", "query", world_map) == (
            subject in ("console", "operator")
        )
        assert not _allowed(acl, subject, "ingress", "put", "@/router/x")  # nothing outside
        for key in ros2:  # the bridge speaks ROS 2 on its session too
            assert _allowed(acl, subject, "ingress", "put", key) == (subject == "bridge")
    # ROS 2 nodes on the same router: their keys, nothing of covswarm (not even to read).
    for key in ros2:
        assert _allowed(acl, "ros2", "ingress", "put", key)
        assert _allowed(acl, "ros2", "egress", "put", key)
    for key in [*owners, *tokens]:
        for flow, message in [
            ("ingress", "put"),
            ("egress", "put"),
            ("ingress", "liveliness_token"),
        ]:
            assert not _allowed(acl, "ros2", flow, message, key)


def test_the_ros2_domains_are_the_bridges() -> None:
    from covswarm.bridge.rmw_zenoh import MAX_DOMAIN_ID
    from covswarm.protocol.access import ROS2_DOMAINS

    assert ROS2_DOMAINS == range(MAX_DOMAIN_ID + 1)


# ---- forgeries against a real router ----


@pytest.mark.e2e
@pytest.mark.timeout(60)
def test_only_agent_i_commands_robot_i(endpoint: str, creds: Path) -> None:
    swarm = protocol.new_swarm_name()
    forgeries = {
        protocol.cmd_key(swarm, 0): [("operator", None), ("agent", 1), ("robot", 0)],
        protocol.agent_state_key(swarm, 0): [("agent", 1), ("coordinator", None)],
        protocol.beacon_key(swarm, 0, 0, 0): [("agent", 1), ("bridge", None)],
    }  # fmt: skip
    with join(endpoint, creds, "robot", 0) as robot:
        inboxes = {key: Inbox(robot, key) for key in forgeries}
        for key, hostiles in forgeries.items():
            for role, i in hostiles:
                with join(endpoint, creds, role, i) as hostile:
                    time.sleep(SETTLE)
                    hostile.put(key, b"forged")
        with join(endpoint, creds, "agent", 0) as agent:  # the owner, after the forgeries
            time.sleep(SETTLE)
            for key in forgeries:
                agent.put(key, b"legitimate")
            for key, inbox in inboxes.items():
                assert inbox.wait_for(b"legitimate"), key
        time.sleep(SETTLE)
    for key, inbox in inboxes.items():
        assert [p for _, p in inbox.items] == [b"legitimate"], key


@pytest.mark.e2e
@pytest.mark.timeout(60)
def test_only_the_coordinator_publishes_the_domain_and_status(endpoint: str, creds: Path) -> None:
    swarm = protocol.new_swarm_name()
    keys = [protocol.domain_key(swarm), protocol.status_key(swarm), protocol.world_key(swarm)]
    with join(endpoint, creds, "agent", 2) as agent:
        inboxes = [Inbox(agent, key) for key in keys]
        for role, i in [("agent", 0), ("operator", None), ("console", None), ("bridge", None)]:
            with join(endpoint, creds, role, i) as hostile:
                time.sleep(SETTLE)
                for key in keys:
                    hostile.put(key, b"forged")
        with join(endpoint, creds, "coordinator") as coordinator:
            time.sleep(SETTLE)
            for key in keys:
                coordinator.put(key, b"legitimate")
            for inbox in inboxes:
                assert inbox.wait_for(b"legitimate")
        time.sleep(SETTLE)
    for inbox in inboxes:
        assert [p for _, p in inbox.items] == [b"legitimate"]


@pytest.mark.e2e
@pytest.mark.timeout(60)
@pytest.mark.parametrize("service", [protocol.steer_key, protocol.world_map_key])
def test_a_fake_steering_service_gets_no_queries(endpoint: str, creds: Path, service) -> None:
    """Steering, and the map's picture: only the coordinator is asked."""
    swarm = protocol.new_swarm_name()
    key = service(swarm)
    asked: dict[str, int] = {"coordinator": 0, "fake": 0}

    def answer(name: str):
        def reply(query) -> None:
            asked[name] += 1
            query.reply(key, name.encode())

        return reply

    with (
        join(endpoint, creds, "coordinator") as coordinator,
        join(endpoint, creds, "operator") as fake,
        join(endpoint, creds, "agent", 1) as agent,
    ):
        coordinator.declare_queryable(key, answer("coordinator"))
        fake.declare_queryable(key, answer("fake"))
        time.sleep(SETTLE)
        for role in ("operator", "console"):
            with join(endpoint, creds, role) as client:
                time.sleep(SETTLE)
                replies = [r.ok.payload.to_bytes() for r in client.get(key, timeout=3.0) if r.ok]
                assert replies == [b"coordinator"], role
        assert [r for r in agent.get(key, timeout=1.0) if r.ok] == []  # agents may not ask
    assert asked == {"coordinator": 2, "fake": 0}


@pytest.mark.e2e
@pytest.mark.timeout(60)
def test_squatted_claims_and_liveliness_tokens_are_refused(endpoint: str, creds: Path) -> None:
    from covswarm.runtime.claims import claim

    swarm = protocol.new_swarm_name()
    squats = [
        protocol.claim_key(swarm, "robot", 30, "squat"),
        protocol.alive_key(swarm, "robot", 30),
        protocol.alive_key(swarm, "agent", 0),
        protocol.alive_key(swarm, "coordinator", 0),
        protocol.claim_key(swarm, "coordinator", 0, "squat"),
    ]
    everything = f"covswarm/{swarm}/**"
    with join(endpoint, creds, "agent", 1) as squatter, join(endpoint, creds, "console") as seer:
        held = [squatter.liveliness().declare_token(k) for k in squats]
        own = squatter.liveliness().declare_token(protocol.alive_key(swarm, "agent", 1))
        time.sleep(SETTLE)
        alive = [str(r.ok.key_expr) for r in seer.liveliness().get(everything, timeout=2.0) if r.ok]
        assert alive == [protocol.alive_key(swarm, "agent", 1)]  # its own token, nothing else
        with join(endpoint, creds, "robot", 30) as robot:
            token = claim(robot, swarm, "robot", 30)
            assert token is not None  # `covswarm robot --id 30` would start
            token.undeclare()
        del held, own


@pytest.mark.e2e
@pytest.mark.timeout(60)
def test_a_process_of_several_ids_holds_one_group_certificate(endpoint: str, creds: Path) -> None:
    swarm = protocol.new_swarm_name()
    with join(endpoint, creds, "robot", [5, 6, 7]) as robot:
        inbox = Inbox(robot, protocol.all_cmds_selector(swarm))
        with join(endpoint, creds, "agent", [5, 6, 7]) as brains:
            time.sleep(SETTLE)
            brains.put(protocol.cmd_key(swarm, 1), b"not mine")
            for i in (5, 6, 7):
                brains.put(protocol.cmd_key(swarm, i), f"cmd {i}".encode())
            assert inbox.wait_for(b"cmd 7")
            time.sleep(SETTLE)
    assert sorted(p for _, p in inbox.items) == [b"cmd 5", b"cmd 6", b"cmd 7"]


@pytest.mark.e2e
@pytest.mark.timeout(60)
def test_a_robot_group_publishes_only_its_own_robots_poses(endpoint: str, creds: Path) -> None:
    """A robot process of an auto-packed run (robot-8-9) puts its robots' poses; the router
    drops its poses of robots 7 and 10 and the agent group's (agent-8-10) forged poses."""
    swarm = protocol.new_swarm_name()
    with join(endpoint, creds, "operator") as listener:
        inbox = Inbox(listener, protocol.all_poses_selector(swarm))
        with (
            join(endpoint, creds, "robot", ROBOT_GROUP) as robots,
            join(endpoint, creds, "agent", AGENT_GROUP) as brains,
        ):
            time.sleep(SETTLE)
            for i in (7, 8, 9, 10):
                brains.put(protocol.pose_key(swarm, i), f"forged {i}".encode())
                robots.put(protocol.pose_key(swarm, i), f"pose {i}".encode())
            assert inbox.wait_for(b"pose 9")
            time.sleep(SETTLE)
    assert sorted(p for _, p in inbox.items) == [b"pose 8", b"pose 9"]


@pytest.mark.e2e
@pytest.mark.timeout(60)
def test_routers_of_two_hosts_relay_only_what_their_clients_may_send(creds: Path) -> None:
    """Host B's router connects to host A's with the router certificate: agent 0 on B
    commands robot 0 on A, an operator on B cannot (B refuses it at the entry)."""
    swarm = protocol.new_swarm_name()
    key = protocol.cmd_key(swarm, 0)
    with secured_router(creds) as host_a, secured_router(creds, host_a) as host_b:
        with join(host_a, creds, "robot", 0) as robot:
            inbox = Inbox(robot, key)
            with (
                join(host_b, creds, "operator") as hostile,
                join(host_b, creds, "agent", 0) as agent,
            ):
                # The routers link up in the background: resend until one arrives.
                assert wait_until(lambda: agent.put(key, b"legitimate") or bool(inbox.items), 15)
                hostile.put(key, b"forged")
                agent.put(key, b"after")
                assert inbox.wait_for(b"after")
                time.sleep(SETTLE)
    assert set(p for _, p in inbox.items) == {b"legitimate", b"after"}


@pytest.mark.e2e
@pytest.mark.timeout(90)
def test_forged_commands_do_not_move_a_secured_robot(endpoint: str, creds: Path) -> None:
    """Issue 21's probe against a real `covswarm robot --id 0 --secure`: valid
    WheelCommands from an operator and from agent 1 at 50 Hz leave it where it is; the same
    commands from agent 0 move it (so the robot was listening)."""
    from covswarm.deploy.plan import covswarm_argv

    swarm = protocol.new_swarm_name()
    argv = [*covswarm_argv(), "robot", "--id", "0", "--connect", endpoint, "--swarm", swarm]
    robot = subprocess.Popen(
        [*argv, "--secure", str(creds)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
    )
    poses: list[protocol.Pose] = []
    try:
        with join(endpoint, creds, "console") as watcher:
            watcher.declare_subscriber(
                protocol.pose_key(swarm, 0),
                lambda s: poses.append(protocol.Pose.decode(s.payload.to_bytes())),
            )
            assert wait_until(lambda: len(poses) > 3, 30), "the secured robot sent no pose"

            def drive(role: str, i: int | None, seconds: float) -> None:
                with join(endpoint, creds, role, i) as sender:
                    time.sleep(SETTLE)
                    end, seq = time.monotonic() + seconds, 0
                    while time.monotonic() < end:
                        seq += 1
                        command = protocol.WheelCommand(
                            id=0, left=0.2, right=0.2, stamp=time.time(), seq=seq,
                            pose_stamp=poses[-1].stamp,
                        )  # fmt: skip
                        sender.put(protocol.cmd_key(swarm, 0), command.encode())
                        time.sleep(0.02)

            start = poses[-1]
            drive("operator", None, 1.5)
            drive("agent", 1, 1.5)
            time.sleep(SETTLE)
            still = poses[-1]
            assert still.seq > start.seq  # poses kept coming while it was attacked
            assert (still.x, still.y) == (start.x, start.y)
            drive("agent", 0, 1.0)
            time.sleep(SETTLE)
            moved = poses[-1]
            assert abs(moved.x - still.x) + abs(moved.y - still.y) > 0.05
    finally:
        robot.terminate()
        robot.wait(timeout=30)
    assert robot.returncode in (0, -15), robot.stderr.read()[-2000:]


@pytest.mark.e2e
def test_covswarm_run_refuses_before_starting_when_a_certificate_is_missing(
    creds: Path, tmp_path: Path
) -> None:
    """A packed run needs group certificates (agent-0-1, ...) the folder lacks: the launcher
    says so and exits 2 before any router or child starts, instead of waiting for tokens
    that children without certificates never declare."""
    started = time.monotonic()
    done = subprocess.run(
        [*covswarm_argv(), "run", "--secure", str(creds),
         "--agents", "4", "--agents-per-process", "2", "--out", str(tmp_path / "run")],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    assert "lacks agent-0-1" in done.stderr and "--group 0-1" in done.stderr
    assert time.monotonic() - started < 30
    assert not (tmp_path / "run" / "logs").exists()


def test_credentials_want_a_folder_of_their_own(tmp_path: Path, monkeypatch) -> None:
    """An empty DIRECTORY (a variable unset in a script) or "." put the CA's private key in
    the working directory, among whatever else it holds."""
    from click.testing import CliRunner

    from covswarm.protocol.security import credentials_command

    monkeypatch.chdir(tmp_path)
    for directory in ("", "."):
        done = CliRunner().invoke(credentials_command, [directory, "--ids", "0"])
        assert done.exit_code == 2 and "name a folder of its own" in done.output, done.output
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "file").write_text("")
    done = CliRunner().invoke(
        credentials_command, [str(tmp_path / "file" / "secure"), "--ids", "0"]
    )
    assert done.exit_code == 1 and "Not a directory" in done.output, done.output


def test_credentials_go_only_into_a_new_folder_or_a_credentials_folder(
    tmp_path: Path, monkeypatch
) -> None:
    """``covswarm credentials ..`` or a folder of other files would put the CA's private
    key among them: refused, naming what is there, and nothing written. An empty folder
    and a credentials folder (to add identities to) are fine."""
    from click.testing import CliRunner

    from covswarm.protocol.security import credentials_command

    project = tmp_path / "project"
    (project / "src").mkdir(parents=True)
    (project / "notes.txt").write_text("mine\n")
    for directory, cwd in ((str(project), tmp_path), ("..", project / "src")):
        monkeypatch.chdir(cwd)
        done = CliRunner().invoke(credentials_command, [directory, "--ids", "0"])
        assert done.exit_code == 2, done.output
        assert "is not a credentials folder" in done.output and "give a new folder" in done.output
        assert sorted(p.name for p in project.iterdir()) == ["notes.txt", "src"]
    assert "notes.txt, src" in done.output  # the files found, named
    with pytest.raises(ValueError, match="not a credentials folder"):
        issue_credentials(project, agents=[0])  # the library refuses it too
    monkeypatch.chdir(tmp_path)
    (tmp_path / "empty").mkdir()
    for args in (["empty", "--ids", "0"], ["empty", "--ids", "1"]):  # new, then added to
        done = CliRunner().invoke(credentials_command, args)
        assert done.exit_code == 0, done.output
    assert {"agent-0", "agent-1"} <= {e["name"] for e in read_identities(tmp_path / "empty")}


def test_a_new_router_host_keeps_the_names_given_before(tmp_path: Path) -> None:
    """``--host`` issues the router's certificate again: with the new names and the ones it
    had, so the clients of an address named before are not refused after it."""
    from covswarm.protocol.certificates import certificate_names

    folder = issue_credentials(tmp_path / "lab", hosts=["10.0.0.7", "robots.lab"])
    issue_credentials(folder, hosts=["192.168.1.10"])
    names = certificate_names(folder / "router" / "cert.pem")
    for host in ("127.0.0.1", "localhost", "10.0.0.7", "robots.lab", "192.168.1.10"):
        assert names.covers(host), (host, names)
    issue_credentials(folder, agents=[4])  # no --host: the certificate is not issued again
    assert certificate_names(folder / "router" / "cert.pem") == names
