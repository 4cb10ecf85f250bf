"""Secured mode: TLS on every link and user/password authentication at the router.

By default covswarm runs zero-configuration on plain TCP (loopback in ``covswarm run``).
With ``--secure DIR`` every process encrypts its link with TLS, checks the router's
certificate against a CA, and logs in with a user name and password; the router refuses a
process that does not present valid credentials, so it can neither publish to nor
subscribe on the swarm's keys. The folder holds:

- ``ca.pem``: the CA certificate that signed the router's certificate (every process);
- ``cert.pem`` and ``key.pem``: the router's certificate, whose subject alternative names
  must include the host (name or IP) clients connect to, and its private key (router only);
- ``credentials``: ``user:password`` lines. The router accepts every line; a client logs
  in with the first line, so a machine's copy of the folder can hold only its own line
  (and no ``key.pem``).

``covswarm credentials DIR`` (:func:`make_test_credentials`) writes a throw-away folder
for one machine: a fresh CA, a router certificate for 127.0.0.1/localhost and one random
password. It uses the ``openssl`` command-line tool.
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import subprocess
import tempfile
from pathlib import Path
from typing import Any

import click

CA, CERT, KEY, CREDENTIALS = "ca.pem", "cert.pem", "key.pem", "credentials"
CERT_DAYS = 30  # test credentials are throw-away


def read_credentials(directory: Path) -> list[tuple[str, str]]:
    """The ``user:password`` lines of ``directory/credentials``; ValueError if malformed."""
    path = Path(directory) / CREDENTIALS
    pairs = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        user, sep, password = line.partition(":")
        if not (sep and user and password) or any(c.isspace() for c in user):
            raise ValueError(f"{path}:{number}: expected 'user:password'")
        pairs.append((user, password))
    if not pairs:
        raise ValueError(f"{path}: no 'user:password' line")
    return pairs


def apply_security(config: Any, directory: Path, mode: str) -> None:
    """Insert the TLS and user/password keys for ``mode`` into a zenoh.Config.

    A router needs ca.pem, cert.pem, key.pem and credentials (its dictionary); a client or
    peer needs ca.pem and credentials (it logs in with the first line). Raises ValueError
    naming a missing or malformed file, so a misconfigured process fails at start-up
    instead of silently running unsecured.
    """
    directory = Path(directory).resolve()
    needed = (CA, CERT, KEY, CREDENTIALS) if mode == "router" else (CA, CREDENTIALS)
    missing = [name for name in needed if not (directory / name).is_file()]
    if missing:
        raise ValueError(f"secure folder {directory} lacks {', '.join(missing)}")
    user, password = read_credentials(directory)[0]

    def put(key: str, value: object) -> None:
        config.insert_json5(key, json.dumps(value))

    put("transport/link/tls/root_ca_certificate", str(directory / CA))
    if mode == "router":
        put("transport/link/tls/listen_certificate", str(directory / CERT))
        put("transport/link/tls/listen_private_key", str(directory / KEY))
        put("transport/auth/usrpwd/dictionary_file", str(directory / CREDENTIALS))
    else:
        put("transport/auth/usrpwd/user", user)
        put("transport/auth/usrpwd/password", password)


def _openssl(*args: str) -> None:
    subprocess.run(["openssl", *args], check=True, capture_output=True, timeout=60)


def make_test_credentials(directory: Path, user: str = "covswarm") -> Path:
    """Write a throw-away secure folder for one machine and return its path.

    A fresh CA (whose key is discarded, so nothing else can ever be signed with it), a
    router certificate for 127.0.0.1 and localhost signed by it, and ``user`` with a random
    password. Private files are created readable by the owner only. Raises RuntimeError if
    the ``openssl`` tool is missing.
    """
    if not user or ":" in user or any(c.isspace() for c in user):
        raise ValueError(f"user name must be non-empty without ':' or spaces, got {user!r}")
    if shutil.which("openssl") is None:
        raise RuntimeError("make_test_credentials needs the 'openssl' command-line tool")
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    ec = ("-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes")
    with tempfile.TemporaryDirectory() as scratch:
        ca_key, csr = Path(scratch) / "ca.key", Path(scratch) / "router.csr"
        _openssl(
            "req", "-x509", *ec, "-keyout", str(ca_key), "-out", str(directory / CA),
            "-days", str(CERT_DAYS), "-subj", "/CN=covswarm test CA",
            "-addext", "basicConstraints=critical,CA:TRUE",
            "-addext", "keyUsage=critical,keyCertSign,cRLSign",
        )  # fmt: skip
        _openssl(
            "req", *ec, "-keyout", str(directory / KEY), "-out", str(csr),
            "-subj", "/CN=covswarm router",
        )  # fmt: skip
        extensions = Path(scratch) / "router.ext"
        extensions.write_text(
            "basicConstraints=critical,CA:FALSE\n"
            "keyUsage=critical,digitalSignature,keyEncipherment\n"
            "extendedKeyUsage=serverAuth,clientAuth\n"
            "subjectAltName=IP:127.0.0.1,DNS:localhost\n"
        )
        _openssl(
            "x509", "-req", "-in", str(csr), "-CA", str(directory / CA), "-CAkey", str(ca_key),
            "-CAcreateserial", "-CAserial", str(Path(scratch) / "ca.srl"),
            "-out", str(directory / CERT), "-days", str(CERT_DAYS), "-extfile", str(extensions),
        )  # fmt: skip
    (directory / KEY).chmod(0o600)
    # Created owner-only before the password is written into it.
    fd = os.open(directory / CREDENTIALS, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    os.fchmod(fd, 0o600)
    with os.fdopen(fd, "w") as out:
        out.write(f"{user}:{secrets.token_urlsafe(18)}\n")
    return directory


SECURE_OPTION = click.option(
    "--secure",
    type=click.Path(exists=True, file_okay=False, path_type=Path),
    default=None,
    help="Secured mode: folder with ca.pem, credentials (and cert.pem, key.pem for the "
    "router); endpoints must be tls/. See `covswarm credentials`.",
)


@click.command("credentials")
@click.argument("directory", type=click.Path(file_okay=False, path_type=Path))
@click.option("--user", default="covswarm", show_default=True, help="User name to create.")
def credentials_command(directory: Path, user: str) -> None:
    """Write throw-away TLS certificates and a password for `--secure` on this machine."""
    try:
        make_test_credentials(directory, user)
    except (RuntimeError, ValueError, subprocess.CalledProcessError) as exc:
        raise click.ClickException(str(exc)) from exc
    click.echo(f"secure folder written to {directory} (use: covswarm run --secure {directory})")
