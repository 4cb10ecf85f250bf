"""X.509 for the secured mode, with pyca ``cryptography``: what a certificate says of whom
it names (its subject's common name and its subject alternative names) and of its trust
(its validity period, its key identifier and its issuer's), whether a private key is the
one a certificate certifies, and the keys and certificates ``covswarm credentials`` issues.
No signature is verified here: zenoh's TLS does that.

The secured mode (covswarm.protocol.security) checks with it before a session opens what
would otherwise fail in silence: a process presenting another identity's certificate (the
router then takes it for that identity and drops what it sends as its own), and a router
listening on an address its certificate does not name, a certificate expired or not yet
valid, one issued by another CA than the folder's, and a private key that is not the
certificate's (each refused by TLS with zenoh's bare "Unable to connect", the same words
as no router at all).

Importing this module loads ``cryptography`` (some 30 ms): the modules every process imports
(protocol.security, protocol.session) import it only where a secure folder is read.
"""

from __future__ import annotations

import ipaddress
import re
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta
from pathlib import Path
from typing import TypeVar

from cryptography import x509
from cryptography.exceptions import UnsupportedAlgorithm
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.hazmat.primitives.asymmetric.types import (
    CertificateIssuerPrivateKeyTypes,
    PrivateKeyTypes,
)
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

# The PEM armour only: a file of several certificates is read for its first, as before.
_PEM = re.compile(rb"-----BEGIN CERTIFICATE-----.+?-----END CERTIFICATE-----", re.DOTALL)
_T = TypeVar("_T")
# What cryptography raises for a certificate whose DER or extensions do not read.
_UNREADABLE = (ValueError, x509.DuplicateExtension, x509.UnsupportedGeneralNameType)


@dataclass(frozen=True)
class Names:
    """``common_name``: the subject's CN (None without one); ``alt_names``: its subject
    alternative names as openssl writes them, "DNS:localhost", "IP:127.0.0.1"."""

    common_name: str | None
    alt_names: frozenset[str]

    def covers(self, host: str) -> bool:
        """Whether a client connecting to ``host`` (an IP address or a name) finds it named."""
        try:
            return f"IP:{ipaddress.ip_address(host.strip('[]'))}" in self.alt_names
        except ValueError:
            return f"dns:{host.lower()}" in {n.lower() for n in self.alt_names}


@dataclass(frozen=True)
class Trust:
    """``not_before``, ``not_after``: the validity period (UTC); ``key_id``: its subject
    key identifier, ``authority_key_id``: its issuer's (None without the extension; a CA
    of ``covswarm credentials`` and the certificates it issues have both)."""

    not_before: datetime
    not_after: datetime
    key_id: bytes | None
    authority_key_id: bytes | None


def _extension(certificate: x509.Certificate, kind: type[_T]) -> _T | None:
    try:
        return certificate.extensions.get_extension_for_class(kind).value
    except x509.ExtensionNotFound:
        return None


def _names(certificate: x509.Certificate) -> Names:
    # The last CN, as a reader of the RDN sequence in order would keep.
    common = certificate.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    value = common[-1].value if common else None
    common_name = value.decode("utf-8", errors="replace") if isinstance(value, bytes) else value
    alt_names: set[str] = set()
    if (alt := _extension(certificate, x509.SubjectAlternativeName)) is not None:
        alt_names |= {f"DNS:{name}" for name in alt.get_values_for_type(x509.DNSName)}
        alt_names |= {f"IP:{address}" for address in alt.get_values_for_type(x509.IPAddress)}
    return Names(common_name, frozenset(alt_names))


def _trust(certificate: x509.Certificate) -> Trust:
    own = _extension(certificate, x509.SubjectKeyIdentifier)
    issuer = _extension(certificate, x509.AuthorityKeyIdentifier)
    return Trust(
        certificate.not_valid_before_utc,
        certificate.not_valid_after_utc,
        None if own is None else own.key_identifier,
        None if issuer is None else issuer.key_identifier,
    )


def load_certificate(path: Path) -> x509.Certificate:
    """The first certificate of the PEM file at ``path``, its extensions read; ValueError
    naming the file if it holds none that reads."""
    match = _PEM.search(Path(path).read_bytes())
    if match is None:
        raise ValueError(f"{path}: no PEM certificate in it")
    try:
        certificate = x509.load_pem_x509_certificate(match.group(0))
        certificate.extensions  # noqa: B018 (parsed on first use: a bad one fails here)
    except _UNREADABLE as exc:
        raise ValueError(f"{path}: not a readable certificate ({exc})") from None
    return certificate


def certificate_names(path: Path) -> Names:
    """The names of the first certificate of the PEM file at ``path``; ValueError naming
    the file if it holds none that reads."""
    return _names(load_certificate(path))


def certificate_trust(path: Path) -> Trust:
    """The validity and key identifiers of the first certificate of the PEM file at
    ``path``; ValueError naming the file if it holds none that reads."""
    return _trust(load_certificate(path))


def load_private_key(path: Path) -> PrivateKeyTypes:
    """The private key of the PEM file at ``path``; ValueError naming the file, in one line,
    unless it holds an unencrypted one that reads (zenoh takes no passphrase)."""
    data = Path(path).read_bytes()
    if b"PRIVATE KEY-----" not in data:
        raise ValueError(f"{path}: no PEM private key in it")
    try:
        return serialization.load_pem_private_key(data, password=None)
    except TypeError:  # cryptography's word for "encrypted, and no password given"
        raise ValueError(
            f"{path}: an encrypted private key (zenoh reads unencrypted ones)"
        ) from None
    except (ValueError, UnsupportedAlgorithm):
        raise ValueError(f"{path}: not a readable private key") from None


def key_matches(key: PrivateKeyTypes, certificate: x509.Certificate) -> bool:
    """Whether ``key`` is the private key of the public key ``certificate`` certifies."""
    der, spki = serialization.Encoding.DER, serialization.PublicFormat.SubjectPublicKeyInfo
    return key.public_key().public_bytes(der, spki) == certificate.public_key().public_bytes(
        der, spki
    )


def new_key() -> ec.EllipticCurvePrivateKey:
    """A new EC P-256 private key (what ``openssl req -newkey ec`` made with P-256)."""
    return ec.generate_private_key(ec.SECP256R1())


def key_pem(key: PrivateKeyTypes) -> bytes:
    """``key`` as unencrypted PKCS#8 PEM ("BEGIN PRIVATE KEY"), which zenoh's rustls reads."""
    return key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )


def certificate_pem(certificate: x509.Certificate) -> bytes:
    return certificate.public_bytes(serialization.Encoding.PEM)


def _general_name(name: str) -> x509.GeneralName:
    """``"IP:10.0.0.5"`` or ``"DNS:robots.lab"`` (openssl's spelling, as :class:`Names`)."""
    kind, _, value = name.partition(":")
    if kind == "IP":
        return x509.IPAddress(ipaddress.ip_address(value))
    if kind == "DNS":
        return x509.DNSName(value)
    raise ValueError(f"subject alternative name {name!r}: expected IP:... or DNS:...")


def _builder(
    common_name: str, key: PrivateKeyTypes, issuer: x509.Name, now: datetime, days: int
) -> x509.CertificateBuilder:
    # Whole seconds: the validity times are encoded to the second.
    start = now.replace(microsecond=0)
    return (
        x509.CertificateBuilder()
        .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name)]))
        .issuer_name(issuer)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(start)
        .not_valid_after(start + timedelta(days=days))
        .add_extension(
            x509.SubjectKeyIdentifier.from_public_key(key.public_key()),
            critical=False,
        )
    )


def make_ca(
    key: CertificateIssuerPrivateKeyTypes, common_name: str, now: datetime, days: int
) -> x509.Certificate:
    """A self-signed CA certificate of ``key`` valid ``days`` from ``now`` (UTC), with the
    extensions ``openssl req -x509`` gave it: CA:TRUE and keyCertSign, cRLSign (both
    critical), and its key identifier as its subject's and its authority's."""
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name)])
    own = x509.SubjectKeyIdentifier.from_public_key(key.public_key())
    usage = x509.KeyUsage(
        digital_signature=False, content_commitment=False, key_encipherment=False,
        data_encipherment=False, key_agreement=False, key_cert_sign=True, crl_sign=True,
        encipher_only=False, decipher_only=False,
    )  # fmt: skip
    return (
        _builder(common_name, key, name, now, days)
        .add_extension(x509.AuthorityKeyIdentifier.from_issuer_subject_key_identifier(own), False)
        .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
        .add_extension(usage, critical=True)
        .sign(key, hashes.SHA256())
    )


def make_certificate(
    key: PrivateKeyTypes,
    common_name: str,
    alt_names: Sequence[str],
    ca: x509.Certificate,
    ca_key: CertificateIssuerPrivateKeyTypes,
    now: datetime,
    days: int,
) -> x509.Certificate:
    """The certificate of ``key`` for ``common_name``, signed by ``ca`` (whose private key
    is ``ca_key``) and valid ``days`` from ``now`` (UTC), for TLS on either side: CA:FALSE,
    digitalSignature and keyEncipherment (both critical), serverAuth and clientAuth, the
    subject alternative names ``alt_names`` (``"IP:..."``, ``"DNS:..."``) if any, and the
    key identifiers of its subject and of the CA's (which the start-up check compares)."""
    ca_key_id = ca.extensions.get_extension_for_class(x509.SubjectKeyIdentifier).value
    usage = x509.KeyUsage(
        digital_signature=True, content_commitment=False, key_encipherment=True,
        data_encipherment=False, key_agreement=False, key_cert_sign=False, crl_sign=False,
        encipher_only=False, decipher_only=False,
    )  # fmt: skip
    builder = (
        _builder(common_name, key, ca.subject, now, days)
        .add_extension(
            x509.AuthorityKeyIdentifier.from_issuer_subject_key_identifier(ca_key_id), False
        )
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(usage, critical=True)
        .add_extension(
            x509.ExtendedKeyUsage(
                [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]
            ),
            critical=False,
        )
    )
    if alt_names:
        builder = builder.add_extension(
            x509.SubjectAlternativeName([_general_name(n) for n in alt_names]), critical=False
        )
    return builder.sign(ca_key, hashes.SHA256())
