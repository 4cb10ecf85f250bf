"""What a certificate names (covswarm.protocol.certificates), read against openssl's own
reading of the certificates ``covswarm credentials`` issues (made with cryptography: openssl
is the independent reference here), and the silent failures it turns into refusals at
start-up: another identity's certificate, a router listening on an address its certificate
does not name, a certificate expired or of another CA."""

from __future__ import annotations

import re
import shutil
import subprocess
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest

from covswarm.protocol.certificates import Names, certificate_names, certificate_trust
from covswarm.protocol.security import CERT_DAYS, check_trust, issue_credentials
from covswarm.protocol.session import check_router_hosts, session_config


@pytest.fixture(scope="module", autouse=True)
def openssl(require) -> None:
    require(shutil.which("openssl") is not None, "needs openssl (apt-get install openssl)")


@pytest.fixture(scope="module")
def secure(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("secure")
    return issue_credentials(
        folder, agents=[0, 1], robots=[0, 1], hosts=["robots.lab", "10.0.0.5", "::1"]
    )


def openssl_names(path: Path) -> Names:
    text = subprocess.run(
        ["openssl", "x509", "-noout", "-subject", "-ext", "subjectAltName", "-in", str(path)],
        capture_output=True, text=True, check=True,
    ).stdout  # fmt: skip
    cn = re.search(r"subject=.*?CN\s*=\s*([^,\n]+)", text)
    alt = re.findall(r"(DNS|IP Address):([^,\s]+)", text)
    names = {f"{'IP' if kind.startswith('IP') else 'DNS'}:{value}" for kind, value in alt}
    return Names(cn.group(1).strip() if cn else None, frozenset(names))


def test_the_names_read_are_openssls(secure: Path) -> None:
    certificates = [secure / "ca.pem", *sorted(secure.glob("*/cert.pem"))]
    assert len(certificates) >= 10
    for path in certificates:
        ours, theirs = certificate_names(path), openssl_names(path)
        assert ours.common_name == theirs.common_name, path
        # openssl prints IPv6 addresses in full: compare them as addresses
        assert {n.replace("IP:0:0:0:0:0:0:0:1", "IP:::1") for n in theirs.alt_names} == set(
            ours.alt_names
        ), path
    router = certificate_names(secure / "router" / "cert.pem")
    assert router.common_name == "router"
    assert router.covers("127.0.0.1") and router.covers("ROBOTS.lab") and router.covers("[::1]")
    assert not router.covers("127.0.0.2") and not router.covers("other.lab")


def test_what_is_not_a_certificate_is_refused_with_the_file(tmp_path: Path) -> None:
    (tmp_path / "none.pem").write_text("hello")
    with pytest.raises(ValueError, match="none.pem: no PEM certificate"):
        certificate_names(tmp_path / "none.pem")
    (tmp_path / "junk.pem").write_text(
        "-----BEGIN CERTIFICATE-----\nMIIBAAAA\n-----END CERTIFICATE-----\n"
    )
    with pytest.raises(ValueError, match="junk.pem: not a readable certificate"):
        certificate_names(tmp_path / "junk.pem")


def test_another_identitys_certificate_is_refused_before_the_session(
    secure: Path, tmp_path: Path
) -> None:
    swapped = tmp_path / "swapped"
    swapped.mkdir()
    shutil.copy(secure / "ca.pem", swapped / "ca.pem")
    shutil.copytree(secure / "robot-1", swapped / "robot-0")
    with pytest.raises(ValueError, match="is robot-1's certificate, not robot-0's"):
        session_config(["tls/127.0.0.1:7447"], secure=swapped, role="robot", id=0)
    session_config(["tls/127.0.0.1:7447"], secure=secure, role="robot", id=0)  # its own


def openssl_trust(path: Path) -> tuple[datetime, datetime, bytes | None, bytes | None]:
    text = subprocess.run(
        ["openssl", "x509", "-noout", "-dates", "-text", "-in", str(path)],
        capture_output=True, text=True, check=True,
    ).stdout  # fmt: skip

    def when(field: str) -> datetime:
        stamp = re.search(rf"{field}=(.+)", text).group(1).strip()  # type: ignore[union-attr]
        return datetime.strptime(stamp, "%b %d %H:%M:%S %Y GMT").replace(tzinfo=timezone.utc)

    def key_id(title: str) -> bytes | None:
        found = re.search(rf"{title} Key Identifier:\s*\n\s*(?:keyid:)?([0-9A-F:]+)", text)
        return bytes.fromhex(found.group(1).replace(":", "")) if found else None

    return when("notBefore"), when("notAfter"), key_id("Subject"), key_id("Authority")


def test_the_validity_and_key_ids_read_are_openssls(secure: Path) -> None:
    for path in [secure / "ca.pem", *sorted(secure.glob("*/cert.pem"))]:
        trust = certificate_trust(path)
        expected = openssl_trust(path)
        assert (trust.not_before, trust.not_after, trust.key_id) == expected[:3], path
        assert trust.authority_key_id == expected[3], path
    ca = certificate_trust(secure / "ca.pem")
    assert certificate_trust(secure / "agent-0" / "cert.pem").authority_key_id == ca.key_id


def openssl_text(*args: str) -> str:
    return subprocess.run(["openssl", *args], capture_output=True, text=True, check=True).stdout


def test_openssl_verifies_what_covswarm_credentials_issues(secure: Path) -> None:
    """The keys and certificates made in-process (cryptography), read by openssl: every
    certificate verifies against ca.pem, carries the extensions the openssl command line
    gave it (and zenoh's TLS was given), lasts CERT_DAYS days, and certifies the P-256 key
    beside it, which is unencrypted PKCS#8 PEM."""
    ca = openssl_text("x509", "-noout", "-text", "-in", str(secure / "ca.pem"))
    assert re.search(r"Basic Constraints: critical\s+CA:TRUE", ca)
    assert re.search(r"Key Usage: critical\s+Certificate Sign, CRL Sign", ca)
    for folder in sorted(p.parent for p in secure.glob("*/cert.pem")):
        cert, key = folder / "cert.pem", folder / "key.pem"
        verified = subprocess.run(
            ["openssl", "verify", "-x509_strict", "-CAfile", str(secure / "ca.pem"), str(cert)],
            capture_output=True, text=True,
        )  # fmt: skip
        assert verified.returncode == 0 and verified.stdout.strip().endswith("OK"), verified
        text = openssl_text("x509", "-noout", "-text", "-in", str(cert))
        assert re.search(r"Basic Constraints: critical\s+CA:FALSE", text), folder
        assert re.search(r"Key Usage: critical\s+Digital Signature, Key Encipherment", text)
        assert "TLS Web Server Authentication, TLS Web Client Authentication" in text
        assert "Signature Algorithm: ecdsa-with-SHA256" in text
        start, end, _, _ = openssl_trust(cert)
        assert end - start == timedelta(days=CERT_DAYS), folder
        assert key.read_text().startswith("-----BEGIN PRIVATE KEY-----\n"), folder  # PKCS#8
        assert "ASN1 OID: prime256v1" in openssl_text("pkey", "-noout", "-text", "-in", str(key))
        public = openssl_text("pkey", "-pubout", "-in", str(key))
        assert public == openssl_text("x509", "-noout", "-pubkey", "-in", str(cert)), folder
    router = openssl_text(
        "x509", "-noout", "-ext", "subjectAltName", "-in", str(secure / "router" / "cert.pem")
    )
    assert "IP Address:127.0.0.1, DNS:localhost" in router


def test_an_expired_or_foreign_certificate_is_refused_before_the_session(
    secure: Path, tmp_path: Path
) -> None:
    check_trust(secure, "robot-0")  # today: fine
    until = certificate_trust(secure / "robot-0" / "cert.pem").not_after
    with pytest.raises(ValueError, match="ca.pem expired on .*: make a new secure folder"):
        check_trust(secure, "robot-0", now=until + timedelta(days=1))
    before = certificate_trust(secure / "ca.pem").not_before
    with pytest.raises(ValueError, match="valid only from .*clock behind"):
        check_trust(secure, "robot-0", now=before - timedelta(days=1))
    other = issue_credentials(tmp_path / "other", agents=[0], robots=[0])
    shutil.rmtree(other / "robot-0")
    shutil.copytree(secure / "robot-0", other / "robot-0")  # another CA's robot 0
    with pytest.raises(ValueError, match="robot-0/cert.pem was issued by another CA than"):
        session_config(["tls/127.0.0.1:7447"], secure=other, role="robot", id=0)


def test_a_router_on_an_address_its_certificate_does_not_name_is_refused(secure: Path) -> None:
    check_router_hosts(secure, ["tls/127.0.0.1:7447", "tls/0.0.0.0:7447", "tls/[::1]:7447"])
    check_router_hosts(secure, ["tls/robots.lab:7447", "tls/10.0.0.5:7447"])
    with pytest.raises(ValueError, match="not 127.0.0.2") as refused:
        session_config(None, ["tls/127.0.0.2:7447"], "router", secure=secure)
    # the command it names keeps the names the certificate has
    assert "--host 10.0.0.5 --host ::1 --host robots.lab --host 127.0.0.2" in str(refused.value)


@pytest.mark.e2e
def test_the_commands_refuse_them_in_one_line(secure: Path, tmp_path: Path) -> None:
    from covswarm.deploy.plan import covswarm_argv

    swapped = tmp_path / "swapped"
    swapped.mkdir()
    shutil.copy(secure / "ca.pem", swapped / "ca.pem")
    shutil.copytree(secure / "robot-1", swapped / "robot-0")
    robot = subprocess.run(
        [*covswarm_argv(), "robot", "--id", "0", "--swarm", "x", "--connect",
         "tls/127.0.0.1:7447", "--secure", str(swapped)],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert robot.returncode == 2 and "robot-1's certificate" in robot.stderr
    run = subprocess.run(
        [*covswarm_argv(), "run", "--secure", str(secure), "--agents", "2", "--router-listen",
         "tls/127.0.0.2:7447", "--out", str(tmp_path / "run")],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert run.returncode == 2 and "not 127.0.0.2" in run.stderr
    assert not (tmp_path / "run" / "logs").exists()
    for done in (robot, run):
        assert "Traceback" not in done.stderr


@pytest.mark.e2e  # a run that got past its checks would start a router and children
def test_covswarm_run_checks_its_routers_files_first_as_covswarm_router_does(
    secure: Path, tmp_path: Path
) -> None:
    """A secure folder without the router's certificate and key, without identities.json,
    or with a router/cert.pem that is no certificate: ``covswarm run`` (whose embedded
    router needs them) says so in one line and exits 2 as ``covswarm router`` does,
    before it writes its output folder or starts anything."""
    from click.testing import CliRunner

    from covswarm.deploy.cli import main

    broken = {}
    for name, breaks in (
        ("no-router", lambda d: shutil.rmtree(d / "router")),
        ("no-identities", lambda d: (d / "identities.json").unlink()),
        ("junk-router", lambda d: (d / "router" / "cert.pem").write_text("junk\n")),
    ):
        broken[name] = tmp_path / name
        shutil.copytree(secure, broken[name])
        breaks(broken[name])
    said = {
        "no-router": "lacks router/cert.pem, router/key.pem",
        "no-identities": "lacks identities.json",
        "junk-router": "router/cert.pem: no PEM certificate in it",
    }
    for name, folder in broken.items():
        out = tmp_path / f"run-{name}"
        run = CliRunner().invoke(
            main, ["run", "--secure", str(folder), "--agents", "2", "--out", str(out)]
        )
        router = CliRunner().invoke(
            main, ["router", "--secure", str(folder), "--listen", "tls/127.0.0.1:7447"]
        )
        for done in (run, router):
            assert done.exit_code == 2, (name, done.output, done.exception)
            assert said[name] in done.output, (name, done.output)
            assert "Traceback" not in done.output
        assert not out.exists()
