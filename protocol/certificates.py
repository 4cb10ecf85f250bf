"""What an X.509 certificate says of whom it names (its subject's common name and its
subject alternative names) and of its trust (its validity period, its key identifier and
its issuer's), read from a PEM file with a small DER reader (no crypto library: no
signature is verified here, zenoh's TLS does that).

The secured mode (covswarm.protocol.security) checks with it before a session opens what
would otherwise fail in silence: a process presenting another identity's certificate (the
router then takes it for that identity and drops what it sends as its own), and a router
listening on an address its certificate does not name, a certificate expired or not yet
valid, and one issued by another CA than the folder's (each refused by TLS with zenoh's
bare "Unable to connect", the same words as no router at all).
"""

from __future__ import annotations

import base64
import ipaddress
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import TypeVar

_PEM = re.compile(rb"-----BEGIN CERTIFICATE-----(.+?)-----END CERTIFICATE-----", re.DOTALL)
_COMMON_NAME = bytes.fromhex("550403")  # OID 2.5.4.3
_ALT_NAMES = bytes.fromhex("551d11")  # OID 2.5.29.17
_SUBJECT_KEY_ID = bytes.fromhex("551d0e")  # OID 2.5.29.14
_AUTHORITY_KEY_ID = bytes.fromhex("551d23")  # OID 2.5.29.35
_UTC_TIME, _GENERALIZED_TIME = 0x17, 0x18
_KEY_ID = 0x80  # AuthorityKeyIdentifier's keyIdentifier [0]
_T = TypeVar("_T")
_SEQUENCE, _SET, _OID, _OCTETS = 0x30, 0x31, 0x06, 0x04
_VERSION, _EXTENSIONS = 0xA0, 0xA3  # [0] and [3] of TBSCertificate
_DNS, _IP = 0x82, 0x87  # GeneralName's dNSName [2] and iPAddress [7]


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


def _tlv(data: bytes, at: int) -> tuple[int, int, int]:
    """(tag, start, end) of the DER element at ``at``: its content is data[start:end]."""
    if at + 2 > len(data):
        raise ValueError("truncated DER")
    tag, length, start = data[at], data[at + 1], at + 2
    if length & 0x80:
        count = length & 0x7F
        if count == 0 or count > 4 or start + count > len(data):
            raise ValueError("bad DER length")
        length, start = int.from_bytes(data[start : start + count], "big"), start + count
    if start + length > len(data):
        raise ValueError("truncated DER")
    return tag, start, start + length


def _children(data: bytes, start: int, end: int) -> list[tuple[int, int, int]]:
    out, at = [], start
    while at < end:
        tag, s, e = _tlv(data, at)
        out.append((tag, s, e))
        at = e
    return out


def _fields(der: bytes) -> list[tuple[int, int, int]]:
    """The TBSCertificate fields of the DER certificate ``der`` after its version: serial,
    signature algorithm, issuer, validity, subject, public key, [extensions]; ValueError if
    it is not one."""
    tag, s, e = _tlv(der, 0)
    if tag != _SEQUENCE:
        raise ValueError("not a certificate")
    tbs = _children(der, s, e)[0]
    fields = _children(der, tbs[1], tbs[2])
    if fields and fields[0][0] == _VERSION:
        fields = fields[1:]
    if len(fields) < 6:
        raise ValueError("not a certificate")
    return fields


def _extensions(der: bytes, fields: list[tuple[int, int, int]]) -> Iterator[tuple[bytes, int]]:
    """(OID, where its value starts) of each extension: the value's own DER element, which
    the extension's OCTET STRING wraps."""
    for tag, s, e in fields[6:]:
        if tag != _EXTENSIONS:
            continue
        for _, xs, xe in _children(der, *_children(der, s, e)[0][1:]):
            parts = _children(der, xs, xe)
            yield der[parts[0][1] : parts[0][2]], parts[-1][1]


def read_names(der: bytes) -> Names:
    """The names of the DER certificate ``der``; ValueError if it is not one."""
    fields = _fields(der)
    common_name = None
    _, s, e = fields[4]
    for _, rs, re_ in _children(der, s, e):  # SET of SEQUENCE {OID, value}
        for _, as_, ae in _children(der, rs, re_):
            oid, value = _children(der, as_, ae)[:2]
            if der[oid[1] : oid[2]] == _COMMON_NAME:
                common_name = der[value[1] : value[2]].decode("utf-8", errors="replace")
    alt_names: set[str] = set()
    for oid, at in _extensions(der, fields):
        if oid != _ALT_NAMES:
            continue
        _, gs, ge = _tlv(der, at)  # a SEQUENCE of GeneralName
        for kind, ns, ne in _children(der, gs, ge):
            if kind == _DNS:
                alt_names.add("DNS:" + der[ns:ne].decode("ascii", errors="replace"))
            elif kind == _IP:
                alt_names.add(f"IP:{ipaddress.ip_address(der[ns:ne])}")
    return Names(common_name, frozenset(alt_names))


def certificate_names(path: Path) -> Names:
    """The names of the first certificate of the PEM file at ``path``; ValueError naming
    the file if it holds none that reads."""
    return _read_first(path, read_names)


def _read_first(path: Path, read: Callable[[bytes], _T]) -> _T:
    """``read`` of the first certificate of the PEM file at ``path``; ValueError naming the
    file if it holds none that reads."""
    match = _PEM.search(Path(path).read_bytes())
    if match is None:
        raise ValueError(f"{path}: no PEM certificate in it")
    try:
        return read(base64.b64decode(b"".join(match.group(1).split())))
    except (ValueError, IndexError) as exc:
        raise ValueError(f"{path}: not a readable certificate ({exc})") from None


@dataclass(frozen=True)
class Trust:
    """``not_before``, ``not_after``: the validity period (UTC); ``key_id``: its subject
    key identifier, ``authority_key_id``: its issuer's (None without the extension; a CA
    of ``covswarm credentials`` and the certificates it issues have both)."""

    not_before: datetime
    not_after: datetime
    key_id: bytes | None
    authority_key_id: bytes | None


def _time(der: bytes, tag: int, start: int, end: int) -> datetime:
    text = der[start:end].decode("ascii")
    if tag == _UTC_TIME:  # YYMMDDHHMMSSZ, 1950-2049 (RFC 5280)
        year = int(text[:2])
        text = f"{1900 + year if year >= 50 else 2000 + year}{text[2:]}"
    elif tag != _GENERALIZED_TIME:
        raise ValueError("bad validity time")
    return datetime.strptime(text, "%Y%m%d%H%M%SZ").replace(tzinfo=timezone.utc)


def read_trust(der: bytes) -> Trust:
    """The validity and key identifiers of the DER certificate ``der``; ValueError if it is
    not one."""
    fields = _fields(der)
    not_before, not_after = (_time(der, *t) for t in _children(der, *fields[3][1:])[:2])
    key_id = authority = None
    for oid, at in _extensions(der, fields):
        _, vs, ve = _tlv(der, at)
        if oid == _SUBJECT_KEY_ID:  # an OCTET STRING
            key_id = der[vs:ve]
        elif oid == _AUTHORITY_KEY_ID:  # SEQUENCE {[0] keyIdentifier, ...}
            for kind, ks, ke in _children(der, vs, ve):
                if kind == _KEY_ID:
                    authority = der[ks:ke]
    return Trust(not_before, not_after, key_id, authority)


def certificate_trust(path: Path) -> Trust:
    """:func:`read_trust` of the first certificate of the PEM file at ``path``; ValueError
    naming the file if it holds none that reads."""
    return _read_first(path, read_trust)
