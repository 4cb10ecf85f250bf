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
folder: EC P-256 keys and certificates valid ``CERT_DAYS`` days, made in-process
(:mod:`protocol.certificates`).

At start-up a secured process checks its files (:func:`check_secure_folder`) and, while it
runs, ends with an error when its certificate or the CA's expires (:func:`watch_expiry`):
zenoh closes its links then, and a process that ran on would hear and be heard by nobody.
"""

from __future__ import annotations

import ipaddress
import json
import logging
import os
import re
import signal
import tempfile
import threading
from collections.abc import Callable, Iterable, Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import click

from covswarm.protocol.keys import check_id, format_ids, parse_ids

# protocol.certificates (cryptography, ~30 ms to import) is imported where a secure folder
# is read: every process imports this module for its --secure option, most never use it.

log = logging.getLogger("covswarm.security")

CA, CERT, KEY, IDENTITIES = "ca.pem", "cert.pem", "key.pem", "identities.json"
CA_KEY = Path("ca") / "ca.key"
ROUTER = "router"
CERT_DAYS = 365
# s: how far ahead a process that does not know how long it will run warns of its
# certificate's end (watch_expiry).
EXPIRY_NOTICE = 24 * 3600.0
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
    presents: ``ca.pem``, ``name/cert.pem`` (a certificate of that name, valid now and
    issued by that CA: :func:`check_trust`) and ``name/key.pem`` (its key:
    :func:`check_key`), and for the router (``name`` ``router``) a readable
    ``identities.json``; else ValueError saying what is wrong, so a misconfigured process
    (or a launcher, before it starts anything) fails in one line instead of running
    unsecured or being refused by the router in silence."""
    from covswarm.protocol.certificates import certificate_names

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
    check_key(directory, name)
    return directory


def check_trust(directory: Path, name: str, now: datetime | None = None) -> None:
    """ValueError when the TLS handshake of identity ``name`` (its certificate against the
    folder's ``ca.pem``) would fail for a reason a certificate shows: either of them
    expired or not yet valid at ``now`` (default: this machine's clock), or the
    certificate issued by another CA (its authority key identifier is not the CA's key
    identifier). zenoh says only "Unable to connect", the same as for no router at all."""
    from covswarm.protocol.certificates import certificate_trust

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
                "make a new secure folder (covswarm credentials)"
                if path == ca_path
                else issue_again(directory, name)
            )
            raise ValueError(f"{path} expired on {trust.not_after:%Y-%m-%d %H:%M} UTC: {again}")
    if cert.authority_key_id and ca.key_id and cert.authority_key_id != ca.key_id:
        raise ValueError(
            f"{cert_path} was issued by another CA than {ca_path}: copy {name}/ from the "
            "folder whose CA issued it, or issue it again from this one"
        )


def check_key(directory: Path, name: str) -> None:
    """ValueError, in one line naming both files, unless identity ``name``'s ``key.pem`` is
    an unencrypted private key that reads and is the key of its ``cert.pem`` (say one copied
    from another identity's folder, or left by an earlier issue): TLS would fail the
    handshake with zenoh's bare "Unable to connect"."""
    from covswarm.protocol.certificates import key_matches, load_certificate, load_private_key

    key_path, cert_path = directory / name / KEY, directory / name / CERT
    try:
        key = load_private_key(key_path)
    except OSError as exc:
        raise ValueError(f"cannot read {key_path}: {exc.strerror}") from None
    except ValueError as exc:
        raise ValueError(f"{exc}: {issue_again(directory, name)}") from None
    if not key_matches(key, load_certificate(cert_path)):
        raise ValueError(
            f"{key_path} does not belong to {cert_path} (another key's certificate): "
            f"{issue_again(directory, name)}"
        )


def issue_again(directory: Path, name: str) -> str:
    """What to do about identity ``name`` of the secure folder ``directory`` whose files are
    spoilt or expire: its ``covswarm credentials`` command, said as the end of a refusal."""
    from covswarm.protocol.certificates import certificate_names

    options = issue_options([name])
    if name == ROUTER:  # the names it has, or its clients on other hosts would be refused
        try:
            named = certificate_names(directory / ROUTER / CERT).alt_names
        except (OSError, ValueError):
            named = frozenset()
        hosts = sorted(n.partition(":")[2] for n in named)
        options = "".join(f" --host {h}" for h in hosts if h not in ("127.0.0.1", "localhost"))
    command = f"covswarm credentials {directory}{options}"
    if not (directory / CA_KEY).is_file():  # a robot's or a host's folder: no CA key here
        command = (
            f"on the machine that holds the CA's key ({CA_KEY}), covswarm credentials "
            f"<its folder>{options}, then copy {name}/ here"
        )
    return f"remove {name}/ and issue it again ({command})"


def credentials_end(directory: Path, names: Iterable[str]) -> tuple[datetime, Path]:
    """(instant, file) of the first certificate to end among those of the identities
    ``names`` of the secure folder ``directory`` and its ``ca.pem`` (whose end makes every
    certificate of the folder untrusted): when zenoh closes the first of their links.
    ValueError naming a file that is no certificate."""
    from covswarm.protocol.certificates import certificate_trust

    directory = Path(directory)
    # The CA first: of two that end together, issuing the CA's anew is what is needed.
    paths = [directory / CA, *(directory / name / CERT for name in names)]
    return min(((certificate_trust(p).not_after, p) for p in paths), key=lambda end: end[0])


def expires_in(not_after: datetime, now: datetime) -> float:
    """Seconds from ``now`` until ``not_after`` (a certificate's end; negative once past)."""
    return (not_after - now).total_seconds()


def _span(seconds: float) -> str:
    """``seconds`` for a person: "40 s", "12 min", "5.5 h", "3 days"."""
    for unit, size in (("days", 86400.0), ("h", 3600.0), ("min", 60.0)):
        if seconds >= 2 * size:
            return f"{seconds / size:.3g} {unit}"
    return f"{max(seconds, 0.0):.0f} s"


def expiry_warning(
    path: Path, not_after: datetime, now: datetime, planned: float | None = None
) -> str | None:
    """A process's start-up warning about the certificate ``path`` it relies on (its own or
    the CA's), which ends at ``not_after``: a sentence when that falls within ``planned`` s
    of ``now`` (the run the process plans, if it knows it) or else within
    :data:`EXPIRY_NOTICE`; None when it outlasts them."""
    left = expires_in(not_after, now)
    if left > (EXPIRY_NOTICE if planned is None else planned):
        return None
    within = (
        f"within the {_span(planned)} this run plans"
        if planned is not None
        else f"within {_span(EXPIRY_NOTICE)}"
    )
    return (
        f"{path} expires on {not_after:%Y-%m-%d %H:%M:%S} UTC, in {_span(left)} ({within}): "
        "zenoh then closes the links that rely on it, and their processes stop"
    )


def expired_error(path: Path, not_after: datetime, advice: str) -> str:
    """The error a running process logs when the certificate ``path`` ends at ``not_after``."""
    return (
        f"{path} expired on {not_after:%Y-%m-%d %H:%M:%S} UTC: zenoh closed this process's "
        f"links, so it stops (exit status 1); {advice}"
    )


class ExpiryWatch:
    """A process's timer for the end of the certificate it presents (``path``, ending at
    ``not_after``; ``path`` None: open mode, nothing to watch).

    Zenoh closes a link when its certificate expires (``close_link_on_expiration``); the
    process then hears nothing and is heard by nobody, with nothing in its log. At that
    instant the timer logs :func:`expired_error` and calls ``stop`` (default: SIGTERM to the
    main thread, whose handler ends the process's loop as Ctrl-C would: robots held, tokens
    undeclared); leaving the ``with`` block then raises SystemExit(1).
    """

    def __init__(
        self,
        path: Path | None,
        not_after: datetime | None = None,
        advice: str = "",
        stop: Callable[[], None] | None = None,
    ) -> None:
        self.path, self.not_after, self.advice = path, not_after, advice
        self.expired = False
        self._stop = _terminate_main_thread if stop is None else stop
        self._timer: threading.Timer | None = None

    def start(self, now: datetime | None = None) -> None:
        if self.path is None or self.not_after is None:
            return
        now = datetime.now(timezone.utc) if now is None else now
        delay = min(max(expires_in(self.not_after, now), 0.0), threading.TIMEOUT_MAX)
        self._timer = threading.Timer(delay, self._expire)
        self._timer.daemon = True  # never what keeps a finished process alive
        self._timer.start()

    def cancel(self) -> None:
        if self._timer is not None:
            self._timer.cancel()

    def _expire(self) -> None:
        self.expired = True
        assert self.path is not None and self.not_after is not None
        log.error("%s", expired_error(self.path, self.not_after, self.advice))
        self._stop()

    def exit_if_expired(self) -> None:
        """SystemExit(1) once the certificate expired while the process ran."""
        if self.expired:
            raise SystemExit(1)

    def __enter__(self) -> ExpiryWatch:
        self.start()
        return self

    def __exit__(self, kind: type[BaseException] | None, *rest: object) -> None:
        self.cancel()
        if kind is None or issubclass(kind, SystemExit):
            self.exit_if_expired()


def _terminate_main_thread() -> None:
    # The main thread's own handler (runtime.clock.StopFlag, the console's event loop) runs
    # at once, even from a sleep: a signal sent to the process could wake another thread.
    signal.pthread_kill(threading.main_thread().ident or 0, signal.SIGTERM)


def watch_expiry(
    directory: Path | None,
    role: str,
    ids: int | Sequence[int] | None = None,
    planned: float | None = None,
    now: datetime | None = None,
) -> ExpiryWatch:
    """The :class:`ExpiryWatch` of a process presenting the certificate of ``role`` and
    ``ids`` (``router``: the router's) of the secure folder ``directory`` (None: open mode,
    a watch that does nothing), once it logged :func:`expiry_warning` if that or the CA's
    certificate ends within ``planned`` s (the run it plans; None: unknown). The files
    were checked (:func:`check_secure_folder`) when its session was configured."""
    if directory is None:
        return ExpiryWatch(None)
    directory = Path(directory).resolve()
    name = ROUTER if role == ROUTER else identity_name(role, ids)
    now = datetime.now(timezone.utc) if now is None else now
    not_after, path = credentials_end(directory, [name])
    advice = (
        issue_again(directory, name)
        if path.name == CERT
        else "make a new secure folder (covswarm credentials into a fresh folder)"
    )
    if (warning := expiry_warning(path, not_after, now, planned)) is not None:
        log.warning("%s; %s before then", warning, advice)
    return ExpiryWatch(path, not_after, advice)


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


def _write_file(path: Path, data: bytes, mode: int = 0o600) -> None:
    """``data`` into ``path``, replaced whole: written to a file created owner-only (never
    readable by others, even for an instant, whatever the umask), then given ``mode``."""
    fd, scratch = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    try:
        with os.fdopen(fd, "wb") as file:
            file.write(data)
        os.chmod(scratch, mode)
        os.replace(scratch, path)
    except BaseException:
        Path(scratch).unlink(missing_ok=True)
        raise


def _load_ca(directory: Path) -> tuple[Any, Any]:
    """The CA's certificate and private key, for issuing; ValueError if they do not read or
    do not go together (whatever it signed would be trusted by nobody)."""
    from covswarm.protocol.certificates import key_matches, load_certificate, load_private_key

    ca, ca_key = load_certificate(directory / CA), load_private_key(directory / CA_KEY)
    if not key_matches(ca_key, ca):
        raise ValueError(f"{directory / CA_KEY} is not the key of {directory / CA}: cannot issue")
    return ca, ca_key


def _issue(directory: Path, name: str, alt_names: Sequence[str], ca: Any, ca_key: Any) -> None:
    """Key and certificate for ``name`` in ``directory/name/``, signed by the CA."""
    from covswarm.protocol.certificates import (
        certificate_pem,
        key_pem,
        make_certificate,
        new_key,
    )

    folder = directory / name
    folder.mkdir(mode=0o700, exist_ok=True)
    key = new_key()
    now = datetime.now(timezone.utc)
    certificate = make_certificate(key, name, alt_names, ca, ca_key, now, CERT_DAYS)
    _write_file(folder / KEY, key_pem(key))
    _write_file(folder / CERT, certificate_pem(certificate))


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
    existing ones (issuing again one whose folder was removed); a folder of other files is
    refused (:func:`check_credentials_target`). Private files are owner-only from creation.
    """
    from covswarm.protocol.certificates import (
        certificate_names,
        certificate_pem,
        key_pem,
        make_ca,
        new_key,
    )

    alt_names = _router_alt_names(hosts)  # bad input refused before anything is written
    directory = Path(directory)
    check_credentials_target(directory)
    directory.mkdir(parents=True, exist_ok=True)
    known = read_identities(directory) if (directory / IDENTITIES).exists() else []
    if not (directory / CA_KEY).is_file():
        if (directory / CA).exists():
            raise ValueError(f"{directory} has a ca.pem but not its key {CA_KEY}: cannot issue")
        (directory / CA_KEY.parent).mkdir(mode=0o700, exist_ok=True)
        ca_key = new_key()
        ca = make_ca(ca_key, "covswarm CA", datetime.now(timezone.utc), CERT_DAYS)
        _write_file(directory / CA_KEY, key_pem(ca_key))
        _write_file(directory / CA, certificate_pem(ca), mode=0o644)
    ca, ca_key = _load_ca(directory)
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
        _issue(directory, ROUTER, alt_names, ca, ca_key)
    for role, ids in wanted:
        name = identity_name(role, ids or None)
        if name in names and (directory / name / CERT).is_file():
            continue
        _issue(directory, name, (), ca, ca_key)
        if name not in names:
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
    except ValueError as exc:
        raise click.ClickException(str(exc)) from exc
    except OSError as exc:  # a folder that cannot be made there
        raise click.ClickException(f"{directory}: {exc.strerror or exc}") from None
    click.echo(
        f"credentials written to {directory}: give each machine {directory / CA} and its "
        f"own sub-folders; keep {directory / CA_KEY} on this machine only"
    )
