"""The secured mode's credentials checked by cryptography's own verifier, and the failures
it refuses or reports that zenoh would leave silent or opaque: a private key that is not
its certificate's (zenoh: "Unable to connect"), a key file that does not read, certificates
built expired or not yet valid, and a certificate that expires while its process runs
(zenoh closes the link; the process used to run on with an empty log).

Certificates of unusual validity are built here with cryptography's CertificateBuilder,
signed by the folder's CA for the identity's own key, so that only their validity differs.
"""

from __future__ import annotations

import logging
import os
import shutil
import subprocess
import sys
import threading
import time
from datetime import datetime, timedelta, timezone
from ipaddress import ip_address
from pathlib import Path

import pytest
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID
from cryptography.x509.verification import (
    ClientVerifier,
    Criticality,
    ExtensionPolicy,
    PolicyBuilder,
    Store,
    VerificationError,
)

from covswarm.deploy.plan import covswarm_argv
from covswarm.deploy.router import free_port
from covswarm.protocol.security import (
    EXPIRY_NOTICE,
    ExpiryWatch,
    credentials_end,
    expires_in,
    expiry_warning,
    issue_credentials,
    watch_expiry,
)
from covswarm.protocol.session import check_router_folder, session_config

ENDPOINT = ["tls/127.0.0.1:7447"]  # configured only: no session is opened with it
NOW = datetime(2030, 6, 1, 12, 0, tzinfo=timezone.utc)


@pytest.fixture(scope="module")
def secure(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("secure")
    return issue_credentials(
        folder, agents=[0, 1], robots=[0, 1], hosts=["robots.lab", "10.0.0.5"]
    ).resolve()


def copy_of(secure: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(secure, tmp_path / "secure")).resolve()


def load(path: Path) -> x509.Certificate:
    return x509.load_pem_x509_certificate(path.read_bytes())


def build_certificate(folder: Path, name: str, start: datetime, end: datetime) -> None:
    """Replace ``name/cert.pem`` by a certificate of its own key from ``start`` to ``end``,
    signed by the folder's CA, built here (not by covswarm.protocol.certificates)."""
    ca = load(folder / "ca.pem")
    ca_key = serialization.load_pem_private_key((folder / "ca" / "ca.key").read_bytes(), None)
    key = serialization.load_pem_private_key((folder / name / "key.pem").read_bytes(), None)
    ca_id = ca.extensions.get_extension_for_class(x509.SubjectKeyIdentifier).value
    certificate = (
        x509.CertificateBuilder()
        .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)]))
        .issuer_name(ca.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(start)
        .not_valid_after(end)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(
            x509.ExtendedKeyUsage(
                [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]
            ),
            critical=False,
        )
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), False)
        .add_extension(x509.AuthorityKeyIdentifier.from_issuer_subject_key_identifier(ca_id), False)
        .sign(ca_key, hashes.SHA256())
    )
    (folder / name / "cert.pem").write_bytes(certificate.public_bytes(serialization.Encoding.PEM))


# ---- what covswarm credentials writes ----


def test_cryptographys_verifier_accepts_each_certificate_for_its_use(
    secure: Path, tmp_path: Path
) -> None:
    """Every identity's certificate verifies as a TLS client against ca.pem, and the router's
    as a server on each name it was issued for and no other (the web PKI's rules, as
    rustls's webpki applies them); another folder's CA trusts none of them."""
    ca = load(secure / "ca.pem")
    # A client certificate names no host: webpki does not ask it to.
    ee = ExtensionPolicy.webpki_defaults_ee().may_be_present(
        x509.SubjectAlternativeName, Criticality.AGNOSTIC, None
    )

    def clients(ca: x509.Certificate) -> ClientVerifier:
        return (
            PolicyBuilder()
            .store(Store([ca]))
            .extension_policies(ca_policy=ExtensionPolicy.webpki_defaults_ca(), ee_policy=ee)
            .build_client_verifier()
        )

    certificates = sorted(secure.glob("*/cert.pem"))
    assert len(certificates) == 10  # router, 5 single roles, agents and robots 0 and 1
    for path in certificates:
        clients(ca).verify(load(path), [])
    router = load(secure / "router" / "cert.pem")
    servers = PolicyBuilder().store(Store([ca]))
    for host in ("127.0.0.1", "localhost", "robots.lab", "10.0.0.5"):
        try:
            subject: x509.GeneralName = x509.IPAddress(ip_address(host))
        except ValueError:
            subject = x509.DNSName(host)
        servers.build_server_verifier(subject).verify(router, [])
    with pytest.raises(VerificationError):
        servers.build_server_verifier(x509.DNSName("other.lab")).verify(router, [])
    other = load(issue_credentials(tmp_path / "other") / "ca.pem")
    for path in certificates:
        with pytest.raises(VerificationError):
            clients(other).verify(load(path), [])


def test_keys_and_folders_are_owner_only_whatever_the_umask(tmp_path: Path) -> None:
    old = os.umask(0)  # the most permissive: nothing is taken away from what is asked
    try:
        folder = issue_credentials(tmp_path / "lab", agents=[0], robots=[0])
    finally:
        os.umask(old)
    assert (folder / "ca").stat().st_mode & 0o777 == 0o700
    assert (folder / "ca" / "ca.key").stat().st_mode & 0o777 == 0o600
    assert (folder / "ca.pem").stat().st_mode & 0o777 == 0o644
    for sub in sorted(p.parent for p in folder.glob("*/cert.pem")):
        assert sub.stat().st_mode & 0o777 == 0o700, sub
        assert (sub / "key.pem").stat().st_mode & 0o777 == 0o600, sub
        assert (sub / "cert.pem").stat().st_mode & 0o777 == 0o600, sub
        assert sorted(p.name for p in sub.iterdir()) == ["cert.pem", "key.pem"]  # no scratch


# ---- refused at start-up ----


def test_a_key_that_is_not_its_certificates_is_refused_naming_both_files(
    secure: Path, tmp_path: Path
) -> None:
    """robot-1's key copied into robot-0/: refused in one line naming both files and the
    command that issues robot 0 again; following it makes a folder that passes."""
    from click.testing import CliRunner

    from covswarm.deploy.cli import main

    folder = copy_of(secure, tmp_path)
    shutil.copy(folder / "robot-1" / "key.pem", folder / "robot-0" / "key.pem")
    with pytest.raises(ValueError) as refused:
        session_config(ENDPOINT, secure=folder, role="robot", id=0)
    said = str(refused.value)
    assert said == (
        f"{folder}/robot-0/key.pem does not belong to {folder}/robot-0/cert.pem (another key's "
        f"certificate): remove robot-0/ and issue it again (covswarm credentials {folder} "
        "--robot-ids 0)"
    )
    robot = CliRunner().invoke(
        main,
        ["robot", "--id", "0", "--swarm", "x", "--connect", ENDPOINT[0], "--secure", str(folder)],
    )
    assert robot.exit_code == 2 and "robot-0/key.pem does not belong to" in robot.output
    assert "Traceback" not in robot.output
    shutil.rmtree(folder / "robot-0")  # as the refusal says
    issue_credentials(folder, robots=[0])
    session_config(ENDPOINT, secure=folder, role="robot", id=0)
    # the router's too, whose advice keeps the names it has
    shutil.copy(folder / "robot-1" / "key.pem", folder / "router" / "key.pem")
    with pytest.raises(ValueError, match=r"router/key.pem does not belong to .*router/cert.pem"):
        check_router_folder(folder)
    with pytest.raises(ValueError, match=r"--host 10\.0\.0\.5 --host robots\.lab\)$"):
        check_router_folder(folder)


def test_a_key_file_that_does_not_read_is_refused_in_one_line(secure: Path, tmp_path: Path) -> None:
    folder = copy_of(secure, tmp_path)
    key = folder / "agent-1" / "key.pem"
    original = serialization.load_pem_private_key(key.read_bytes(), None)
    encrypted = original.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.BestAvailableEncryption(b"passphrase"),
    )
    for content, said in (
        (b"hello\n", "key.pem: no PEM private key in it"),
        (b"-----BEGIN PRIVATE KEY-----\nMIIBAAAA\n-----END PRIVATE KEY-----\n", "not a readable"),
        (encrypted, "key.pem: an encrypted private key (zenoh reads unencrypted ones)"),
    ):
        key.write_bytes(content)
        with pytest.raises(ValueError) as refused:
            session_config(ENDPOINT, secure=folder, role="agent", id=1)
        assert said in str(refused.value) and "\n" not in str(refused.value)
        assert str(refused.value).endswith("--agent-ids 1)")
    # On a robot's machine (no CA key there) the command is run where the CA's key is.
    (folder / "ca" / "ca.key").unlink()
    with pytest.raises(ValueError, match="on the machine that holds the CA's key"):
        session_config(ENDPOINT, secure=folder, role="agent", id=1)


def test_certificates_built_expired_or_not_yet_valid_are_refused(
    secure: Path, tmp_path: Path
) -> None:
    folder = copy_of(secure, tmp_path)
    now = datetime.now(timezone.utc).replace(microsecond=0)
    session_config(ENDPOINT, secure=folder, role="robot", id=0)  # as issued: fine
    build_certificate(folder, "robot-0", now - timedelta(days=400), now - timedelta(days=35))
    with pytest.raises(
        ValueError, match=r"robot-0/cert.pem expired on \d{4}-\d\d-\d\d \d\d:\d\d UTC"
    ):
        session_config(ENDPOINT, secure=folder, role="robot", id=0)
    build_certificate(folder, "robot-0", now + timedelta(days=10), now + timedelta(days=20))
    with pytest.raises(ValueError, match="robot-0/cert.pem is valid only from .*clock behind"):
        session_config(ENDPOINT, secure=folder, role="robot", id=0)
    build_certificate(folder, "robot-0", now - timedelta(days=1), now + timedelta(days=1))
    session_config(ENDPOINT, secure=folder, role="robot", id=0)  # valid now: accepted


# ---- a certificate that ends during a run ----


def test_expires_in_and_the_start_up_warning() -> None:
    path = Path("secure/robot-3/cert.pem")
    assert expires_in(NOW + timedelta(minutes=90), NOW) == 5400.0
    assert expires_in(NOW - timedelta(seconds=5), NOW) == -5.0
    assert EXPIRY_NOTICE == 24 * 3600
    # a process that does not know how long it runs: warned a day ahead
    warning = expiry_warning(path, NOW + timedelta(hours=23), NOW)
    assert warning == (
        "secure/robot-3/cert.pem expires on 2030-06-02 11:00:00 UTC, in 23 h (within 24 h): "
        "zenoh then closes the links that rely on it, and their processes stop"
    )
    assert expiry_warning(path, NOW + timedelta(hours=25), NOW) is None
    # one that does: warned when the run outlasts the certificate, and only then
    planned = 2 * 3600.0
    assert "within the 2 h this run plans" in (
        expiry_warning(path, NOW + timedelta(minutes=90), NOW, planned) or ""
    )
    assert expiry_warning(path, NOW + timedelta(hours=3), NOW, planned) is None
    assert "in 40 s" in (expiry_warning(path, NOW + timedelta(seconds=40), NOW, planned) or "")


def test_the_first_certificate_to_end_is_watched(
    secure: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    folder = copy_of(secure, tmp_path)
    now = datetime.now(timezone.utc).replace(microsecond=0)
    ca_end = load(folder / "ca.pem").not_valid_after_utc
    assert credentials_end(folder, ["robot-0"]) == (ca_end, folder / "ca.pem")  # a tie: the CA
    build_certificate(folder, "robot-0", now - timedelta(days=1), now + timedelta(hours=3))
    build_certificate(folder, "agent-0", now - timedelta(days=1), now + timedelta(days=500))
    ends = credentials_end(folder, ["robot-0", "agent-0"])
    assert ends == (now + timedelta(hours=3), folder / "robot-0" / "cert.pem")
    with caplog.at_level(logging.WARNING, logger="covswarm.security"):
        watch = watch_expiry(folder, "robot", 0)
    assert (watch.not_after, watch.path) == ends
    assert [r.levelname for r in caplog.records] == ["WARNING"]
    assert "robot-0/cert.pem expires on" in caplog.text and "in 3 h (within 24 h)" in caplog.text
    assert f"remove robot-0/ and issue it again (covswarm credentials {folder}" in caplog.text
    caplog.clear()
    watch_expiry(folder, "robot", 0, planned=600.0)  # a 10-minute run: nothing to say
    # agent 0's outlasts the CA: the CA's end is the one watched, and the advice a new folder
    with caplog.at_level(logging.WARNING, logger="covswarm.security"):
        agent = watch_expiry(folder, "agent", 0, planned=500 * 86400.0)
    assert agent.path == folder / "ca.pem" and "make a new secure folder" in caplog.text
    assert watch_expiry(None, "robot", 0).path is None  # open mode: nothing watched


def test_the_watch_stops_the_process_and_exits_non_zero_when_the_certificate_ends(
    caplog: pytest.LogCaptureFixture,
) -> None:
    path = Path("secure/robot-3/cert.pem")
    end = datetime.now(timezone.utc) + timedelta(seconds=0.3)
    stopped = threading.Event()
    watch = ExpiryWatch(path, end, "remove robot-3/ and issue it again", stop=stopped.set)
    with caplog.at_level(logging.ERROR, logger="covswarm.security"):
        with pytest.raises(SystemExit) as exit_status, watch:
            assert stopped.wait(10)  # the process's loop, until its stop
    assert exit_status.value.code == 1
    assert caplog.records[0].getMessage() == (
        f"secure/robot-3/cert.pem expired on {end:%Y-%m-%d %H:%M:%S} UTC: zenoh closed this "
        "process's links, so it stops (exit status 1); remove robot-3/ and issue it again"
    )
    # one that outlasts the process: nothing happens, before or after it ends
    later = ExpiryWatch(
        path, datetime.now(timezone.utc) + timedelta(seconds=0.3), stop=stopped.clear
    )
    with later:
        pass
    time.sleep(0.5)
    assert stopped.is_set() and not later.expired
    with ExpiryWatch(None):  # open mode
        pass


@pytest.mark.e2e  # a launcher, though it finds no router and starts nothing
def test_covswarm_run_warns_of_a_certificate_that_ends_before_the_run_would(
    secure: Path, tmp_path: Path
) -> None:
    """The launcher knows how long its run lasts (the mission and its longest deploy hold):
    a certificate of the run ending within it is said on its console before it starts
    anything (here it then finds no router at --connect)."""
    from click.testing import CliRunner

    from covswarm.deploy.cli import main

    folder = copy_of(secure, tmp_path)
    now = datetime.now(timezone.utc)
    build_certificate(folder, "operator", now - timedelta(minutes=1), now + timedelta(minutes=1))
    nowhere = f"tls/127.0.0.1:{free_port()}"
    args = ["run", "--secure", str(folder), "--agents", "1", "--duration", "30", "--connect"]
    run = CliRunner().invoke(main, [*args, nowhere, "--out", str(tmp_path / "run")])
    assert run.exit_code == 1 and "cannot open a Zenoh session" in run.output, run.output
    said = " ".join(run.output.split())
    assert "warning: " in said and "operator/cert.pem expires on" in said, run.output
    assert "this run plans" in said
    build_certificate(folder, "operator", now - timedelta(minutes=1), now + timedelta(hours=1))
    run = CliRunner().invoke(main, [*args, nowhere, "--out", str(tmp_path / "run-2")])
    assert run.exit_code == 1 and "expires on" not in run.output, run.output


def test_covswarm_steer_warns_of_an_operator_certificate_about_to_end(
    secure: Path, tmp_path: Path
) -> None:
    """A steering request lasts seconds, so it is not watched; the operator is told when
    the credentials it presents end within EXPIRY_NOTICE (here it then finds no router)."""
    from click.testing import CliRunner

    from covswarm.deploy.cli import main

    folder = copy_of(secure, tmp_path)
    now = datetime.now(timezone.utc)
    nowhere = f"tls/127.0.0.1:{free_port()}"
    args = ["steer", "--secure", str(folder), "--connect", nowhere, "--swarm", "s"]
    args += ["--translate", "0.1,0"]
    build_certificate(folder, "operator", now - timedelta(minutes=1), now + timedelta(hours=3))
    run = CliRunner().invoke(main, args)
    said = " ".join(run.output.split())
    assert run.exit_code == 3 and "no answer: cannot join" in said, run.output
    assert "warning: " in said and "operator/cert.pem expires on" in said, run.output
    assert "in 3 h (within 24 h)" in said
    build_certificate(folder, "operator", now - timedelta(minutes=1), now + timedelta(days=2))
    run = CliRunner().invoke(main, args)
    assert run.exit_code == 3 and "expires on" not in run.output, run.output


@pytest.mark.e2e
def test_a_robot_whose_certificate_expires_mid_run_exits_with_the_reason(
    secure: Path, tmp_path: Path
) -> None:
    """A robot process whose certificate ends seconds after it joined (a real router over
    loopback TLS): it is heard while the certificate is valid, then logs the expiry and
    exits with status 1 rather than run on unheard."""
    import zenoh

    from covswarm.protocol import alive_key

    folder = copy_of(secure, tmp_path)
    now = datetime.now(timezone.utc)
    end = now + timedelta(seconds=8)
    build_certificate(folder, "robot-0", now - timedelta(minutes=1), end)
    endpoint, swarm = f"tls/127.0.0.1:{free_port()}", f"expiry{os.getpid()}"
    log = tmp_path / "robot.log"
    with zenoh.open(session_config(None, [endpoint], "router", secure=folder)) as router:
        with log.open("w") as out:
            robot = subprocess.Popen(
                [*covswarm_argv(), "robot", "--id", "0", "--swarm", swarm, "--connect",
                 endpoint, "--secure", str(folder)],
                stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT,
            )  # fmt: skip
        try:
            heard = False
            while not heard and datetime.now(timezone.utc) < end and robot.poll() is None:
                replies = router.liveliness().get(alive_key(swarm, "robot", 0), timeout=1.0)
                heard = any(reply.ok is not None for reply in replies)
            assert heard, log.read_text()  # joined with the certificate while it was valid
            status = robot.wait(timeout=15)
        finally:
            if robot.poll() is None:
                robot.kill()
                robot.wait()
    said = log.read_text()
    assert status == 1, said
    assert "robot-0/cert.pem expires on" in said  # the start-up warning
    assert f"robot-0/cert.pem expired on {end:%Y-%m-%d %H:%M:%S} UTC" in said, said
    assert "Traceback" not in said


def test_open_mode_processes_do_not_import_cryptography() -> None:
    """cryptography (~30 ms to import) is loaded where a secure folder is read, not by the
    processes of an open run: on a machine starting hundreds, import time is start-up."""
    code = (
        "import sys\n"
        "import covswarm.sim_robot.process, covswarm.agent.main, covswarm.coordinator.main\n"
        "from covswarm.protocol.session import session_config\n"
        "session_config(['tcp/127.0.0.1:7447'], role='robot', id=0)\n"
        "assert 'cryptography' not in sys.modules\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
