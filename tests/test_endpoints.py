"""Zenoh endpoints on the command line: refused with the reason before anything starts,
and a session that cannot open (no router there, a port in use) as a one-line error, never
a Python traceback or zenoh's Rust source location."""

from __future__ import annotations

import socket
import subprocess

import pytest

from covswarm.deploy.plan import covswarm_argv
from covswarm.protocol.session import (
    SessionError,
    check_endpoint,
    check_open_listen,
    is_loopback,
    open_session,
    session_config,
)

GOOD = [
    "tcp/127.0.0.1:7447",
    "tcp/0.0.0.0:0",
    "tls/[::1]:7447",
    "tcp/robot-3.lab:7447",
    "udp/10.0.0.1:7447",
    "tcp/127.0.0.1:7447#iface=lo",
    "unixsock-stream//tmp/zenoh.sock",
]
BAD = {
    "foo": "expected <protocol>/<address>",
    "tcp/": "expected <protocol>/<address>",
    "http/127.0.0.1:80": "unknown protocol 'http'",
    "tcp/127.0.0.1": "expected tcp/<host>:<port>",
    "tcp/:7447": "expected tcp/<host>:<port>",
    "tcp/127.0.0.1:x": "port 'x' is not a number",
    "tcp/127.0.0.1:70000": "port '70000' is not a number in 0..65535",
    "tcp/[zz]:7447": "is not an IPv6 address",
    "tcp/a b:7447": "neither an IP address nor a host name",
    "tcp/::1:7447": "neither an IP address nor a host name",
    "": "empty",
}


@pytest.mark.parametrize("endpoint", GOOD)
def test_zenoh_takes_every_endpoint_the_check_passes(endpoint: str) -> None:
    assert check_endpoint(endpoint) == endpoint
    if endpoint.startswith("tls/"):  # TLS needs the secure folder's CA and certificate
        with pytest.raises(ValueError, match="a tls/ endpoint needs --secure DIR"):
            session_config([endpoint])
        return
    session_config([endpoint])  # zenoh parses it (a ZError otherwise)


LOOPBACK = [
    "tcp/127.0.0.1:7447",
    "tcp/127.0.0.2:7447",
    "tcp/[::1]:7447",
    "tcp/localhost:7447",
    "udp/127.0.0.1:7447",
    "unixsock-stream//tmp/zenoh.sock",
]
EXPOSED = [
    "tcp/0.0.0.0:7447",
    "tcp/[::]:7447",
    "tcp/10.0.0.1:7447",
    "tcp/robot-3.lab:7447",
    "udp/192.168.1.10:7447",
    "tcp/[fe80::1]:7447",
]


def test_an_open_router_listens_on_loopback_only() -> None:
    """Beyond loopback a router needs --secure: open, anyone reaching the port would
    command every robot. Refused with what to do instead, before zenoh is configured."""
    assert all(is_loopback(e) for e in LOOPBACK)
    assert not any(is_loopback(e) for e in EXPOSED)
    check_open_listen(LOOPBACK)
    session_config(None, ["tcp/127.0.0.1:0"], "router")
    for endpoint in EXPOSED:
        with pytest.raises(ValueError, match="needs --secure DIR") as refused:
            session_config(None, ["tcp/127.0.0.1:0", endpoint], "router")
        assert endpoint in str(refused.value)
        assert f"tls/{endpoint.partition('/')[2]}" in str(refused.value)
    with pytest.raises(ValueError, match=r"covswarm credentials DIR --host 10\.0\.0\.1\)"):
        check_open_listen(["tcp/10.0.0.1:7447"])


@pytest.mark.e2e
@pytest.mark.parametrize(
    "args",
    [
        ("router", "--listen", "tcp/0.0.0.0:{port}"),
        ("run", "--scenario", "live", "--agents", "2", "--router-listen", "tcp/10.0.0.1:{port}"),
    ],
)
def test_the_commands_refuse_an_open_router_beyond_loopback(args: tuple[str, ...]) -> None:
    port = closed_port()
    done = covswarm(*(a.format(port=port) for a in args))
    assert done.returncode == 2, done.stderr
    assert "a router reachable from other hosts needs --secure DIR" in done.stderr
    assert "Traceback" not in done.stderr


@pytest.mark.parametrize(("endpoint", "reason"), BAD.items())
def test_a_malformed_endpoint_is_refused_with_the_reason(endpoint: str, reason: str) -> None:
    with pytest.raises(ValueError, match="endpoint") as refused:
        check_endpoint(endpoint)
    assert reason in str(refused.value)
    with pytest.raises(ValueError, match="endpoint"):
        session_config([endpoint])  # not zenoh's JSON5 error


def closed_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def test_a_session_with_no_router_there_fails_with_zenohs_reason_alone() -> None:
    with pytest.raises(SessionError) as failed:
        open_session(session_config([f"tcp/127.0.0.1:{closed_port()}"]))
    assert "Unable to connect" in str(failed.value)
    assert ".rs:" not in str(failed.value)


def covswarm(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run(
        [*covswarm_argv(), *args], capture_output=True, text=True, timeout=timeout
    )


@pytest.mark.e2e
@pytest.mark.parametrize(
    "args",
    [
        ("steer", "--connect", "foo", "--swarm", "x", "--translate", "0.1,0"),
        ("console", "--connect", "tcp/127.0.0.1", "--swarm", "x"),
        ("run", "--scenario", "live", "--connect", "foo"),
        ("run", "--scenario", "live", "--router-listen", "tcp/localhost:port"),
        ("agent", "--id", "0", "--connect", "udp/[::1:7447"),
    ],
)
def test_the_commands_refuse_a_malformed_endpoint_as_a_bad_option(args: tuple[str, ...]) -> None:
    done = covswarm(*args)
    assert done.returncode == 2, done.stderr
    assert "Invalid value for '--" in done.stderr and "endpoint" in done.stderr
    assert "Traceback" not in done.stderr


@pytest.mark.e2e
def test_steer_without_a_router_says_no_answer_in_one_line() -> None:
    done = covswarm(
        "steer", "--connect", f"tcp/127.0.0.1:{closed_port()}", "--swarm", "x", "--translate", "1,0"
    )
    assert done.returncode == 3
    assert done.stderr.startswith("no answer: cannot join") and ".rs:" not in done.stderr
    assert "Traceback" not in done.stderr


@pytest.mark.e2e
def test_run_without_a_router_there_or_on_a_busy_port_is_a_one_line_error(tmp_path) -> None:
    missing = covswarm(
        "run", "--scenario", "live", "--agents", "2", "--duration", "5",
        "--connect", f"tcp/127.0.0.1:{closed_port()}", "--out", str(tmp_path / "missing"),
    )  # fmt: skip
    assert missing.returncode == 1
    assert "Error: cannot open a Zenoh session: Unable to connect" in missing.stderr
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        taken = covswarm(
            "run", "--scenario", "live", "--agents", "2", "--duration", "5",
            "--router-listen", f"tcp/127.0.0.1:{port}", "--out", str(tmp_path / "taken"),
        )  # fmt: skip
    assert taken.returncode == 1
    assert "Error: cannot open a Zenoh session:" in taken.stderr
    assert "Address already in use" in taken.stderr
    for done in (missing, taken):
        assert "Traceback" not in done.stderr and ".rs:" not in done.stderr
