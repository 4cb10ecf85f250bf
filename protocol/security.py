"""Secured mode: mutual TLS on every link, one certificate per role, access control at the router.

By default covswarm runs zero-configuration on plain TCP (loopback in ``covswarm run``).
With ``--secure DIR`` every process encrypts its link with TLS and presents its own client
certificate (mutual TLS), whose common name says who it is: ``coordinator``, ``agent-3``,
``robot-3``, ``bridge``, ``console`` or ``operator``. The router refuses a process without
a certificate signed by the swarm's CA, and its access-control list
(:mod:`protocol.access`) lets each identity put, declare and query only the keys of its
role and ids: agent 3 alone commands robot 3, only the coordinator publishes the Domain
and answers steering requests, and so on. The folder holds:

- ``ca.pem``: the CA certificate (every machine);
- ``identities.json``: every identity issued, with its role and ids (the router builds its
  access-control list from it; not secret);
- one sub-folder per identity, ``<name>/cert.pem`` and ``<name>/key.pem``; ``router/`` is
  the router's (its certificate names 127.0.0.1 and localhost, plus every ``--host`` given);
- ``ca/ca.key``: the CA's private key, kept to issue more identities later. It never
  leaves the machine that issues credentials.

A machine receives only ``ca.pem`` and its own sub-folders (the router's machine also
``identities.json``). ``covswarm credentials DIR`` (:func:`issue_credentials`) writes the
folder with the ``openssl`` command-line tool.
"""

from __future__ import annotations

import ipaddress
import json
import os
import re
import shutil
import subprocess
import tempfile
from collections.abc import Iterable, Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import click

from covswarm.protocol.certificates import certificate_names, certificate_trust
from covswarm.protocol.keys import check_id, format_ids, parse_ids

CA, CERT, KEY, IDENTITIES = "ca.pem", "cert.pem", "key.pem", "identities.json"
CA_KEY = Path("ca") / "ca.key"
ROUTER = "router"
CERT_DAYS = 365
# Roles with one identity per robot id, and roles with a single identity.
ID_ROLES = ("agent", "robot")
# ros2: the ROS 2 nodes (rmw_zenoh) a bridge talks to, when they share the swarm's router.
SINGLE_ROLES = ("coordinator", "bridge", "console", "operator", "ros2")
ROLES = (*ID_ROLES, *SINGLE_ROLES)
_HOSTNAME_RE = re.compile(r"^[A-Za-z0-9]([A-Za-z0-9.-]{0,251}[A-Za-z0-9])?$")


def identity_name(role: str, ids: int | Sequence[int] | None = None) -> str:
    """The certificate common name (and sub-folder) of ``role`` with ``ids``.

    ``agent``/``robot`` need ids: one id gives ``agent-3``; several (a process running
    several brains) ``agent-0-4,10`` (:func:`protocol.keys.format_ids`). Other roles take
    none. ValueError otherwise.
    """
    if role not in ROLES:
        raise ValueError(f"role must be one of {ROLES}, got {role!r}")
    if role in SINGLE_ROLES:
        if ids is not None:
            raise ValueError(f"role {role!r} has no id, got {ids!r}")
        return role
    if ids is None:
        raise ValueError(f"role {role!r} needs an id")
    id_list = [ids] if isinstance(ids, int) else list(ids)
    if not id_list:
        raise ValueError(f"role {role!r} needs at least one id")
    return f"{role}-{format_ids([check_id(i) for i in id_list])}"


def read_identities(directory: Path) -> list[dict[str, Any]]:
    """The identities of ``directory/identities.json``: dicts with name, role and ids."""
    path = Path(directory) / IDENTITIES
    try:
        entries = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"cannot read {path}: {exc}") from None
    if not isinstance(entries, list):
        raise ValueError(f"{path}: expected a list of identities")
    for entry in entries:
        if not (isinstance(entry, dict) and entry.get("role") in ROLES):
            raise ValueError(f"{path}: malformed identity {entry!r}")
        ids = entry.get("ids") or None
        if identity_name(entry["role"], ids) != entry.get("name"):
            raise ValueError(f"{path}: identity {entry!r} does not match its role and ids")
    return entries


def apply_security(
    config: Any,
    directory: Path,
    mode: str,
    role: str = "operator",
    ids: int | Sequence[int] | None = None,
) -> None:
    """Insert the mutual-TLS keys (and the router's access control) into a zenoh.Config.

    A router presents ``router/`` and enforces the access-control list built from
    ``identities.json``; any other process presents the certificate of ``role`` and
    ``ids`` (:func:`identity_name`). Raises ValueError naming a missing file, so a
    misconfigured process fails at start-up instead of silently running unsecured.
    """
    from covswarm.protocol.access import access_control

    name = ROUTER if mode == "router" else identity_name(role, ids)
    directory = check_secure_folder(directory, name)

    def put(key: str, value: object) -> None:
        config.insert_json5(key, json.dumps(value))

    put("transport/link/tls/root_ca_certificate", str(directory / CA))
    put("transport/link/tls/enable_mtls", True)
    # A certificate that expires closes the link instead of staying trusted until restart.
    put("transport/link/tls/close_link_on_expiration", True)
    side = "listen" if mode == "router" else "connect"
    put(f"transport/link/tls/{side}_certificate", str(directory / name / CERT))
    put(f"transport/link/tls/{side}_private_key", str(directory / name / KEY))
    if mode == "router":
        # The router also connects to other hosts' routers (--router-connect) with its own.
        put("transport/link/tls/connect_certificate", str(directory / name / CERT))
        put("transport/link/tls/connect_private_key", str(directory / name / KEY))
        put("access_control", access_control(read_identities(directory)))


def check_secure_folder(directory: Path, name: str) -> Path:
    """The secure folder ``directory`` (resolved) if it holds what identity ``name``
    presents: ``ca.pem``, ``name/cert.pem`` (a certificate of that name) and
    ``name/key.pem``, and for the router (``name`` ``router``) a readable
    ``identities.json``; else ValueError saying what is wrong, so a misconfigured process
    (or a launcher, before it starts anything) fails in one line instead of running
    unsecured or being refused by the router in silence."""
    directory = Path(directory).resolve()
    if name != ROUTER:
        require_identities(directory, [name])  # names the command that issues it
    needed = [CA, f"{name}/{CERT}", f"{name}/{KEY}"]
    if name == ROUTER:
        needed.append(IDENTITIES)
    missing = [n for n in needed if not (directory / n).is_file()]
    if missing:
        raise ValueError(f"secure folder {directory} lacks {', '.join(missing)}")
    try:
        presented = certificate_names(directory / name / CERT).common_name
    except OSError as exc:
        raise ValueError(f"cannot read {directory / name / CERT}: {exc.strerror}") from None
    if presented != name:
        # The router knows a process by its certificate's name alone: as this one it would
        # drop, in silence, everything this process sends as itself.
        raise ValueError(
            f"{directory / name / CERT} is {presented}'s certificate, not {name}'s: "
            f"the router would take this process for {presented}"
        )
    if name == ROUTER:
        read_identities(directory)  # its access-control list: malformed, said here
    check_trust(directory, name)
    return directory


def check_trust(directory: Path, name: str, now: datetime | None = None) -> None:
    """ValueError when the TLS handshake of identity ``name`` (its certificate against the
    folder's ``ca.pem``) would fail for a reason a certificate shows: either of them
    expired or not yet valid at ``now`` (default: this machine's clock), or the
    certificate issued by another CA (its authority key identifier is not the CA's key
    identifier). zenoh says only "Unable to connect", the same as for no router at all."""
    now = datetime.now(timezone.utc) if now is None else now
    ca_path, cert_path = directory / CA, directory / name / CERT
    ca, cert = certificate_trust(ca_path), certificate_trust(cert_path)
    for path, trust in ((ca_path, ca), (cert_path, cert)):
        if now < trust.not_before:
            raise ValueError(
                f"{path} is valid only from {trust.not_before:%Y-%m-%d %H:%M} UTC: is this "
                "machine's clock behind?"
            )
        if now > trust.not_after:
            again = (
                "make a new secure folder"
                if path == ca_path
                else f"remove {name}/ and issue it again"
            )
            raise ValueError(
                f"{path} expired on {trust.not_after:%Y-%m-%d %H:%M} UTC: {again} "
                "(covswarm credentials)"
            )
    if cert.authority_key_id and ca.key_id and cert.authority_key_id != ca.key_id:
        raise ValueError(
            f"{cert_path} was issued by another CA than {ca_path}: copy {name}/ from the "
            "folder whose CA issued it, or issue it again from this one"
        )


def require_identities(directory: Path, names: Iterable[str]) -> None:
    """ValueError naming the command that issues whichever of ``names`` (identity names,
    e.g. ``agent-0-9``) ``directory`` lacks; for a launcher to check before it starts
    processes that would each fail on its own."""
    directory = Path(directory)
    if not (directory / CA).is_file() and (directory.parent / CA).is_file():
        # One identity's own folder: issuing into it would make a CA nobody trusts.
        raise ValueError(
            f"{directory} is not a secure folder (no {CA}) but one identity's in "
            f"{directory.parent}: --secure {directory.parent}"
        )
    missing = [n for n in names if not (directory / n / CERT).is_file()]
    if missing:
        command = f"covswarm credentials {directory}{issue_options(missing)}"
        if (directory / CA).is_file() and not (directory / CA_KEY).is_file():
            # A robot's or a host's folder: the CA's key stays on the admin machine.
            command = (
                f"on the machine that holds the CA's key ({CA_KEY}), covswarm credentials "
                f"<its folder>{issue_options(missing)}, then copy "
                f"{', '.join(f'{n}/' for n in missing)} into {directory}"
            )
        raise ValueError(f"secure folder {directory} lacks {', '.join(missing)}: {command}")


def issue_options(names: Iterable[str]) -> str:
    """The ``covswarm credentials`` options that issue the identities ``names`` and no other
    agent or robot: an id or group both roles lack goes in ``--ids``/``--group``, one that
    only one role lacks in that role's option (an auto-packed run hosts its robots in fewer
    processes than its brains, so its robot groups are not its agent groups; a certificate
    no process needs is one more that could command or impersonate robots)."""
    singles: dict[str, set[int]] = {role: set() for role in ID_ROLES}
    groups: dict[str, set[str]] = {role: set() for role in ID_ROLES}
    for name in names:
        role, _, ids = name.partition("-")
        if role in ID_ROLES and ids.isdigit():
            singles[role].add(int(ids))
        elif role in ID_ROLES and ids:
            groups[role].add(ids)
    options = ""
    agent_groups, robot_groups = groups["agent"], groups["robot"]
    for group in sorted(agent_groups | robot_groups, key=parse_ids):
        if group not in robot_groups:
            options += f" --agent-group {group}"
        elif group not in agent_groups:
            options += f" --robot-group {group}"
        else:
            options += f" --group {group}"
    agents, robots = singles["agent"], singles["robot"]
    if agents and agents == robots:
        options += f" --ids {format_ids(sorted(agents))}"
    else:
        options += f" --agent-ids {format_ids(sorted(agents))}" if agents else ""
        options += f" --robot-ids {format_ids(sorted(robots))}" if robots else ""
    return options


def _openssl(*args: str) -> None:
    subprocess.run(["openssl", *args], check=True, capture_output=True, timeout=60)


_EC = ("-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes")


def _issue(directory: Path, name: str, alt_names: Sequence[str]) -> None:
    """Key and certificate for ``name`` in ``directory/name/``, signed by the CA."""
    folder = directory / name
    folder.mkdir(mode=0o700, exist_ok=True)
    with tempfile.TemporaryDirectory() as scratch:
        extensions = Path(scratch) / "ext.cnf"
        lines = [
            "[ext]",
            "basicConstraints=critical,CA:FALSE",
            "keyUsage=critical,digitalSignature,keyEncipherment",
            "extendedKeyUsage=serverAuth,clientAuth",
        ]
        if alt_names:
            lines.append(f"subjectAltName={','.join(alt_names)}")
        extensions.write_text("\n".join(lines) + "\n")
        # umask: the key is created owner-only, never readable by others even for an instant.
        old = os.umask(0o077)
        try:
            _openssl(
                "req", "-x509", *_EC, "-keyout", str(folder / KEY), "-out", str(folder / CERT),
                "-CA", str(directory / CA), "-CAkey", str(directory / CA_KEY),
                "-days", str(CERT_DAYS), "-subj", f"/CN={name}",
                "-config", str(extensions), "-extensions", "ext",
            )  # fmt: skip
        finally:
            os.umask(old)


def _router_alt_names(hosts: Iterable[str]) -> list[str]:
    """subjectAltName entries of the router's certificate: loopback plus ``hosts``."""
    names = []
    for host in ["127.0.0.1", "localhost", *hosts]:
        try:
            names.append(f"IP:{ipaddress.ip_address(host)}")
        except ValueError:
            if not _HOSTNAME_RE.match(host):
                raise ValueError(f"invalid router host {host!r}: a name or an IP") from None
            names.append(f"DNS:{host}")
    return list(dict.fromkeys(names))


def check_credentials_target(directory: Path) -> None:
    """ValueError unless ``directory`` may receive credentials: a new or empty folder, or
    a credentials folder already (it has ``ca/``, ``ca.pem`` or ``identities.json``), to
    which identities are added. Any other folder would get the CA's private key among
    files of its own (``covswarm credentials ..``), named in the message."""
    directory = Path(directory)
    if not directory.is_dir() or any(
        (directory / n).exists() for n in (CA_KEY.parent, CA, IDENTITIES)
    ):
        return
    found = sorted(entry.name for entry in directory.iterdir())
    if found:
        shown = ", ".join(found[:5]) + (f" and {len(found) - 5} more" if len(found) > 5 else "")
        raise ValueError(
            f"{directory} is not a credentials folder (no ca/, identities.json) but holds "
            f"{shown}: give a new folder, e.g. ./secure"
        )


def issue_credentials(
    directory: Path,
    agents: Sequence[int] = (),
    robots: Sequence[int] = (),
    groups: Sequence[Sequence[int]] = (),
    hosts: Sequence[str] = (),
    agent_groups: Sequence[Sequence[int]] = (),
    robot_groups: Sequence[Sequence[int]] = (),
) -> Path:
    """Write (or extend) a secure folder and return its path.

    Creates the CA on first use (kept in ``ca/ca.key``, owner-only), the router's
    certificate (127.0.0.1, localhost and ``hosts``; issued again when ``hosts`` are given,
    with the names it had kept), the coordinator, bridge, console and
    operator, one agent per id of ``agents``, one robot per id of ``robots``, one agent
    and one robot per group of ``groups`` (a process running several brains or simulated
    robots, ``--ids``, presents one certificate for them all), one agent per group of
    ``agent_groups`` and one robot per group of ``robot_groups``.
    Run again on the same folder, it adds identities signed by the same CA and keeps the
    existing ones; a folder of other files is refused (:func:`check_credentials_target`).
    Private files are owner-only. RuntimeError without ``openssl``.
    """
    alt_names = _router_alt_names(hosts)  # bad input refused before anything is written
    directory = Path(directory)
    check_credentials_target(directory)
    if shutil.which("openssl") is None:
        raise RuntimeError("covswarm credentials needs the 'openssl' command-line tool")
    directory.mkdir(parents=True, exist_ok=True)
    known = read_identities(directory) if (directory / IDENTITIES).exists() else []
    if not (directory / CA_KEY).is_file():
        if (directory / CA).exists():
            raise ValueError(f"{directory} has a ca.pem but not its key {CA_KEY}: cannot issue")
        (directory / CA_KEY.parent).mkdir(mode=0o700, exist_ok=True)
        old = os.umask(0o077)
        try:
            _openssl(
                "req", "-x509", *_EC, "-keyout", str(directory / CA_KEY),
                "-out", str(directory / CA), "-days", str(CERT_DAYS),
                "-subj", "/CN=covswarm CA",
                "-addext", "basicConstraints=critical,CA:TRUE",
                "-addext", "keyUsage=critical,keyCertSign,cRLSign",
            )  # fmt: skip
        finally:
            os.umask(old)
        (directory / CA).chmod(0o644)
    wanted: list[tuple[str, list[int]]] = [(role, []) for role in SINGLE_ROLES]
    wanted += [("agent", [i]) for i in agents] + [("robot", [i]) for i in robots]
    wanted += [(role, sorted(set(group))) for group in groups for role in ID_ROLES]
    wanted += [("agent", sorted(set(group))) for group in agent_groups]
    wanted += [("robot", sorted(set(group))) for group in robot_groups]
    names = {entry["name"] for entry in known}
    router = directory / ROUTER / CERT
    if hosts or not router.is_file():
        if router.is_file():  # --host adds names: clients of the earlier ones keep working
            try:
                earlier = certificate_names(router).alt_names
            except ValueError:
                earlier = frozenset()  # not a certificate: nothing to keep
            alt_names += sorted(earlier - set(alt_names))
        _issue(directory, ROUTER, alt_names)
    for role, ids in wanted:
        name = identity_name(role, ids or None)
        if name in names:
            continue
        _issue(directory, name, ())
        known.append({"name": name, "role": role, "ids": ids})
        names.add(name)
    (directory / IDENTITIES).write_text(json.dumps(known, indent=1) + "\n")
    return directory


def make_test_credentials(directory: Path, ids: Sequence[int] = range(16)) -> Path:
    """A secure folder for tests and one-machine runs: agents and robots ``ids``."""
    return issue_credentials(directory, agents=ids, robots=ids)


SECURE_OPTION = click.option(
    "--secure",
    type=click.Path(exists=True, file_okay=False, path_type=Path),
    default=None,
    help="Secured mode: folder from `covswarm credentials` (ca.pem and this process's "
    "certificate); endpoints must be tls/.",
)


def _id_list(ctx: click.Context, param: click.Parameter, value: str | None) -> list[int]:
    try:
        return [] if value is None else parse_ids(value)
    except ValueError as exc:
        raise click.BadParameter(str(exc)) from exc


@click.command("credentials")
@click.argument("directory", type=click.Path(file_okay=False, path_type=Path))
@click.option("--agents", type=click.IntRange(0), default=None, help="Ids 0..N-1 for both.")
@click.option("--ids", callback=_id_list, help="Agent and robot ids, e.g. 0-9 or 0-4,10.")
@click.option("--agent-ids", callback=_id_list, help="Agent ids only (default: --ids).")
@click.option("--robot-ids", callback=_id_list, help="Robot ids only (default: --ids).")
@click.option(
    "--group",
    "groups",
    multiple=True,
    help="One agent and one robot certificate for a process running several ids "
    "(--ids), e.g. 0-49 (repeatable).",
)
@click.option(
    "--agent-group",
    "agent_groups",
    multiple=True,
    help="An agent certificate only, for an agent process running several ids (repeatable).",
)
@click.option(
    "--robot-group",
    "robot_groups",
    multiple=True,
    help="A robot certificate only, for a robot process running several ids (repeatable).",
)
@click.option(
    "--host",
    "hosts",
    multiple=True,
    help="Name or IP of the router's host as other machines reach it (repeatable).",
)
def credentials_command(
    directory: Path,
    agents: int | None,
    ids: list[int],
    agent_ids: list[int],
    robot_ids: list[int],
    groups: tuple[str, ...],
    agent_groups: tuple[str, ...],
    robot_groups: tuple[str, ...],
    hosts: tuple[str, ...],
) -> None:
    """Issue a CA and one certificate per role for `--secure`: router, coordinator, bridge,
    console, operator, one agent and one robot per id. Run again to add identities."""
    if agents is not None and ids:
        raise click.UsageError("give --agents N or --ids, not both")
    if not str(directory).strip() or directory == Path("."):
        # the CA's private key among whatever else the working directory holds
        raise click.BadParameter("name a folder of its own, e.g. ./secure", param_hint="DIRECTORY")
    try:
        check_credentials_target(directory)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="DIRECTORY") from None
    both = list(range(agents)) if agents is not None else ids
    try:
        issue_credentials(
            directory, agent_ids or both, robot_ids or both,
            groups=[parse_ids(group) for group in groups], hosts=hosts,
            agent_groups=[parse_ids(group) for group in agent_groups],
            robot_groups=[parse_ids(group) for group in robot_groups],
        )  # fmt: skip
    except (RuntimeError, ValueError, subprocess.CalledProcessError) as exc:
        raise click.ClickException(str(exc)) from exc
    except OSError as exc:  # a folder that cannot be made there
        raise click.ClickException(f"{directory}: {exc.strerror or exc}") from None
    click.echo(
        f"credentials written to {directory}: give each machine {directory / CA} and its "
        f"own sub-folders; keep {directory / CA_KEY} on this machine only"
    )
