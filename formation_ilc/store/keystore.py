"""An SROS2 keystore for a formation: CA, governance, one enclave per node; its checks.

The layout is SROS2's, so ``ros2 security`` on a full ROS 2 install reads it::

    DIR/public/ca.cert.pem                  the CA's certificate (identity and permissions)
    DIR/public/{identity,permissions}_ca.cert.pem
    DIR/private/ca.key.pem                  the CA's key: stays on the machine that signs
    DIR/enclaves/governance.{xml,p7s}
    DIR/enclaves/<namespace>/<node>/        one enclave: cert.pem, key.pem,
        permissions.{xml,p7s}, governance.p7s, identity_ca.cert.pem, permissions_ca.cert.pem

Enclave files are copies, not links: an enclave folder alone is all a robot needs.
Keys are ECDSA P-256, documents S/MIME signed (detached, text/plain, SHA-256), as SROS2
does. :func:`create` is idempotent: run again for a changed graph it keeps every
certificate that is still valid, re-signs only the permissions that changed, makes the
enclaves that are new and removes those of nodes no longer in the formation.
:func:`verify` is the secure launcher's check before any node starts; it raises
:class:`KeystoreError`, one line naming the file.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path

from cryptography import x509
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.hazmat.primitives.serialization import pkcs7
from cryptography.x509.oid import NameOID

from formation_ilc.config.enclaves import (
    Grant,
    enclave_prefix,
    governance_xml,
    lacking,
    permissions_xml,
)
from formation_ilc.store.atomic import atomic_write_text

__all__ = ["KeystoreError", "Created", "CA_DAYS", "create", "verify", "enclave_dir",
           "sign_smime", "subject_of", "bundle", "enclave_prefixes", "MEMBER_CERTS"]

#: the CA outlives the enclaves it signs; enclaves get ``days`` (``keystore create --days``)
CA_DAYS = 3650
CA_NAME = "formation-ilc CA"
#: files of an enclave that Fast DDS reads (ROS_SECURITY_ENCLAVE_OVERRIDE -> this folder)
ENCLAVE_FILES = ("cert.pem", "key.pem", "permissions.p7s", "governance.p7s",
                 "identity_ca.cert.pem", "permissions_ca.cert.pem")
#: where a host's bundle keeps the other members' certificates (``bundle``)
MEMBER_CERTS = Path("public") / "enclaves"


class KeystoreError(ValueError):
    """A keystore that cannot run the formation: one line, naming the file and why."""


@dataclass
class Created:
    """What :func:`create` did, enclave by enclave (path -> action)."""

    ca: str
    governance: str
    enclaves: dict[str, str]

    def lines(self) -> list[str]:
        out = [f"CA: {self.ca}", f"governance: {self.governance}"]
        out += [f"{path}: {action}" for path, action in sorted(self.enclaves.items())]
        return out


def enclave_dir(keystore: Path, enclave: str) -> Path:
    """The folder of enclave ``/formation/robot_1`` in ``keystore``."""
    return Path(keystore) / "enclaves" / enclave.strip("/")


def subject_of(enclave: str) -> str:
    """The subject of an enclave's certificate, as its permissions name it (SROS2's)."""
    return f"CN={enclave}"


def enclave_prefixes(keystore: Path | str, namespace: str) -> dict[str, bytes]:
    """Node ``/ns/name`` -> the GUID prefix bytes of a participant authenticated in the
    enclave of that path (``config.enclaves.enclave_prefix`` of its certificate's
    subject), for every enclave of ``namespace`` in ``keystore`` whose certificate can be
    read: its own enclaves, and the other members' certificates a host's bundle carries
    (``bundle``; those only if the keystore's CA signed them for the enclave they are filed
    under). A keystore copied without them knows only the enclaves it holds."""
    keystore = Path(keystore)
    out: dict[str, bytes] = {}
    ca: x509.Certificate | None = None
    for root, checked in ((keystore / MEMBER_CERTS, True), (keystore / "enclaves", False)):
        for cert_path in sorted((root / namespace.strip("/")).glob("*/cert.pem")):
            try:
                cert = _read_cert(cert_path)
                name = f"{namespace.rstrip('/')}/{cert_path.parent.name}"
                if checked:  # the CA's, and issued to the enclave it is filed under
                    ca = ca or _read_cert(keystore / "public" / "ca.cert.pem")
                    cert.verify_directly_issued_by(ca)
                    if cert.subject.rfc4514_string() != subject_of(name):
                        continue
            except (KeystoreError, ValueError, TypeError, InvalidSignature):
                continue
            out[name] = enclave_prefix(cert.subject.public_bytes())
    return out


def _key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def _write_private(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as fh:
        fh.write(data)
    os.replace(tmp, path)


def _write_bytes(path: Path, data: bytes) -> bool:
    """Write ``data`` unless the file holds it already; True if written."""
    if path.is_file() and path.read_bytes() == data:
        return False
    atomic_write_text(path, data.decode(), durable=False)
    return True


def _certificate(subject: str, issuer: x509.Name, public: ec.EllipticCurvePublicKey,
                 signer: ec.EllipticCurvePrivateKey, start: datetime, days: int, ca: bool
                 ) -> x509.Certificate:
    return (x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, subject)]))
            .issuer_name(issuer).public_key(public)
            .serial_number(x509.random_serial_number())
            .not_valid_before(start).not_valid_after(start + timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=ca, path_length=None), critical=True)
            .sign(signer, hashes.SHA256()))


def sign_smime(data: bytes, cert: x509.Certificate, key: ec.EllipticCurvePrivateKey) -> bytes:
    """``data`` S/MIME signed by ``cert``/``key``: detached, text/plain, SHA-256 (what Fast
    DDS's access control plugin verifies)."""
    return (pkcs7.PKCS7SignatureBuilder().set_data(data)
            .add_signer(cert, key, hashes.SHA256())
            .sign(serialization.Encoding.SMIME,
                  [pkcs7.PKCS7Options.Text, pkcs7.PKCS7Options.DetachedSignature]))


def _load_ca(keystore: Path, now: datetime, create: bool
             ) -> tuple[x509.Certificate, ec.EllipticCurvePrivateKey, str]:
    cert_path = keystore / "public" / "ca.cert.pem"
    key_path = keystore / "private" / "ca.key.pem"
    if cert_path.exists() or key_path.exists():
        cert = _read_cert(cert_path)
        try:
            key = serialization.load_pem_private_key(key_path.read_bytes(), None)
        except (OSError, ValueError, TypeError) as exc:
            raise KeystoreError(f"{key_path}: not a readable private key ({exc})") from None
        public = cert.public_key()
        if not isinstance(key, ec.EllipticCurvePrivateKey) or \
                not isinstance(public, ec.EllipticCurvePublicKey) or \
                key.public_key().public_numbers() != public.public_numbers():
            raise KeystoreError(f"{key_path}: not the key of {cert_path}")
        return cert, key, "kept"
    if not create:
        raise KeystoreError(f"{cert_path}: missing")
    key = ec.generate_private_key(ec.SECP256R1())
    cert = _certificate(CA_NAME, x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, CA_NAME)]),
                        key.public_key(), key, now, CA_DAYS, ca=True)
    _write_private(key_path, _key_pem(key))
    pem = cert.public_bytes(serialization.Encoding.PEM)
    for name in ("ca.cert.pem", "identity_ca.cert.pem", "permissions_ca.cert.pem"):
        _write_bytes(keystore / "public" / name, pem)
    for name in ("identity_ca.key.pem", "permissions_ca.key.pem"):
        _write_private(keystore / "private" / name, _key_pem(key))
    return cert, key, "created"


def _read_cert(path: Path) -> x509.Certificate:
    try:
        return x509.load_pem_x509_certificate(path.read_bytes())
    except FileNotFoundError:
        raise KeystoreError(f"{path}: missing") from None
    except (OSError, ValueError) as exc:
        raise KeystoreError(f"{path}: not a PEM certificate ({exc})") from None


def _issued_by(cert: x509.Certificate, ca: x509.Certificate) -> bool:
    try:
        cert.verify_directly_issued_by(ca)
    except (ValueError, TypeError, InvalidSignature):
        return False
    return True


def _enclave(keystore: Path, grant: Grant, ca: x509.Certificate,
             ca_key: ec.EllipticCurvePrivateKey, gov_p7s: bytes, now: datetime, days: int
             ) -> str:
    """Make or update one enclave; what was done."""
    d = enclave_dir(keystore, grant.enclave)
    subject = subject_of(grant.enclave)
    action = []
    cert = None
    if (d / "cert.pem").is_file() and (d / "key.pem").is_file():
        try:
            cert = _read_cert(d / "cert.pem")
        except KeystoreError:
            cert = None
        if cert is not None and not (
                _issued_by(cert, ca) and cert.subject.rfc4514_string() == subject
                and cert.not_valid_after_utc > now + timedelta(days=1)):
            cert = None
    if cert is None:
        key = ec.generate_private_key(ec.SECP256R1())
        cert = _certificate(grant.enclave, ca.subject, key.public_key(), ca_key, now, days,
                            ca=False)
        _write_private(d / "key.pem", _key_pem(key))
        _write_bytes(d / "cert.pem", cert.public_bytes(serialization.Encoding.PEM))
        action.append("new identity")
    text = permissions_xml(grant, subject, cert.not_valid_before_utc,
                           cert.not_valid_after_utc)
    if _write_bytes(d / "permissions.xml", text.encode()) or \
            not (d / "permissions.p7s").is_file() or action:
        _write_bytes(d / "permissions.p7s", sign_smime(text.encode(), ca, ca_key))
        action.append("permissions signed")
    pem = ca.public_bytes(serialization.Encoding.PEM)
    for name in ("identity_ca.cert.pem", "permissions_ca.cert.pem"):
        _write_bytes(d / name, pem)
    _write_bytes(d / "governance.p7s", gov_p7s)
    return ", ".join(action) or "unchanged"


def _stale(keystore: Path, namespaces: set[str], keep: set[str]) -> list[Path]:
    """Enclave folders of the formation's namespaces that no grant names."""
    out = []
    for ns in namespaces:
        root = enclave_dir(keystore, ns)
        if root.is_dir():
            out += [p for p in sorted(root.iterdir())
                    if p.is_dir() and (p / "cert.pem").exists()
                    and "/" + str(p.relative_to(keystore / "enclaves")) not in keep]
    return out


def create(keystore: Path, grants: Mapping[str, Grant], *, days: int = 365,
           now: datetime | None = None) -> Created:
    """Make ``keystore`` (or bring it up to date) for the nodes of ``grants``.

    ``days``: validity of each new enclave certificate (and of its permissions), from
    ``now`` (UTC; default the present).
    """
    if days < 1:
        raise KeystoreError(f"--days: {days}: must be at least 1")
    keystore = Path(keystore)
    now = now or datetime.now(UTC)
    ca, ca_key, ca_action = _load_ca(keystore, now, create=True)
    if ca.not_valid_after_utc <= now:
        raise KeystoreError(f"{keystore / 'public' / 'ca.cert.pem'}: expired on "
                            f"{ca.not_valid_after_utc:%Y-%m-%d}; make a new keystore")
    gov = governance_xml().encode()
    enclaves_root = keystore / "enclaves"
    gov_action = "unchanged"
    if _write_bytes(enclaves_root / "governance.xml", gov) or \
            not (enclaves_root / "governance.p7s").is_file() or ca_action == "created":
        _write_bytes(enclaves_root / "governance.p7s", sign_smime(gov, ca, ca_key))
        gov_action = "signed"
    gov_p7s = (enclaves_root / "governance.p7s").read_bytes()
    done = {path: _enclave(keystore, g, ca, ca_key, gov_p7s, now, days)
            for path, g in grants.items()}
    namespaces = {path.rsplit("/", 1)[0] for path in grants}
    for p in _stale(keystore, namespaces, set(grants)):
        shutil.rmtree(p)
        done["/" + str(p.relative_to(enclaves_root))] = "removed (no longer in the formation)"
    return Created(ca_action, gov_action, done)


def bundle(keystore: Path, dest: Path, enclaves: Iterable[str]) -> list[str]:
    """Write ``dest``: a keystore holding only ``enclaves`` (their keys and signed
    permissions), the governance and the CA's certificate; never the CA's private key, nor
    another enclave's key. Every other enclave's certificate (public) goes to
    ``public/enclaves/``: a host's nodes pin each member's name to its enclave
    (``enclave_prefixes``). What it held before is replaced. The enclaves it holds."""
    keystore, dest = Path(keystore), Path(dest)
    names = sorted(set(enclaves))
    if dest.exists():
        shutil.rmtree(dest)
    (dest / "public").mkdir(parents=True)
    (dest / "enclaves").mkdir()
    shutil.copy2(keystore / "public" / "ca.cert.pem", dest / "public" / "ca.cert.pem")
    for name in ("governance.xml", "governance.p7s"):
        shutil.copy2(keystore / "enclaves" / name, dest / "enclaves" / name)
    for enclave in names:
        shutil.copytree(enclave_dir(keystore, enclave), enclave_dir(dest, enclave))
        os.chmod(enclave_dir(dest, enclave) / "key.pem", 0o600)
    for cert in sorted((keystore / "enclaves").rglob("cert.pem")):
        path = cert.parent.relative_to(keystore / "enclaves")
        if "/" + path.as_posix() not in names:
            (dest / MEMBER_CERTS / path).mkdir(parents=True, exist_ok=True)
            shutil.copy2(cert, dest / MEMBER_CERTS / path / "cert.pem")
    return names


def _p7s_signed_by(p7s: Path, ca_cert: Path) -> bool | None:
    """Whether ``p7s`` verifies against ``ca_cert`` (openssl smime); None without openssl."""
    openssl = shutil.which("openssl")
    if openssl is None:
        return None
    out = subprocess.run([openssl, "smime", "-verify", "-in", str(p7s), "-CAfile",
                          str(ca_cert), "-purpose", "any", "-out", os.devnull],
                         capture_output=True, check=False)
    return out.returncode == 0


def _not_after(permissions: Path) -> datetime | None:
    text = permissions.read_text(errors="replace")
    a, b = text.find("<not_after>"), text.find("</not_after>")
    if a < 0 or b < a:
        return None
    try:
        return datetime.strptime(text[a + 11:b].strip(), "%Y-%m-%dT%H:%M:%S").replace(tzinfo=UTC)
    except ValueError:
        return None


def verify(keystore: Path, enclaves: Iterable[str], *, now: datetime | None = None,
           smime: bool = True, grants: Mapping[str, Grant] | None = None) -> None:
    """Check that ``keystore`` can run nodes in ``enclaves`` now; KeystoreError if not.

    Missing files, an expired or not yet valid certificate or permissions document, an
    enclave certificate or signature not from the keystore's CA, an enclave's CA copy that
    is another CA's. ``smime`` also verifies the signed documents (openssl, if present).
    ``grants`` (by enclave path: the run's roster, ``Roster.grants``): each enclave's
    permissions must allow every topic its grant needs (a keystore made for another
    scenario or plant lacks some: the first enclave's missing grants are named).
    """
    keystore = Path(keystore)
    now = now or datetime.now(UTC)
    if not keystore.is_dir():
        raise KeystoreError(f"{keystore}: no such keystore folder (make one with "
                            f"`formation-ilc keystore create {keystore} SCENARIO`)")
    ca_path = keystore / "public" / "ca.cert.pem"
    ca = _read_cert(ca_path)
    _check_validity(ca, ca_path, now)
    gov = keystore / "enclaves" / "governance.p7s"
    if not gov.is_file():
        raise KeystoreError(f"{gov}: missing")
    if smime and _p7s_signed_by(gov, ca_path) is False:
        raise KeystoreError(f"{gov}: not signed by the keystore's CA ({ca_path})")
    granted: list[tuple[Path, Grant]] = []
    for enclave in enclaves:
        d = enclave_dir(keystore, enclave)
        if not d.is_dir():
            raise KeystoreError(f"{d}: missing: no enclave for node {enclave} (re-run "
                                f"`formation-ilc keystore create` for this formation)")
        for name in ENCLAVE_FILES:
            if not (d / name).is_file():
                raise KeystoreError(f"{d / name}: missing")
        for name in ("identity_ca.cert.pem", "permissions_ca.cert.pem"):
            if _read_cert(d / name) != ca:
                raise KeystoreError(f"{d / name}: another CA than the keystore's ({ca_path})")
        cert = _read_cert(d / "cert.pem")
        if not _issued_by(cert, ca):
            raise KeystoreError(f"{d / 'cert.pem'}: not issued by the keystore's CA "
                                f"({ca_path})")
        if cert.subject.rfc4514_string() != subject_of(enclave):
            raise KeystoreError(f"{d / 'cert.pem'}: subject {cert.subject.rfc4514_string()}, "
                                f"expected {subject_of(enclave)}")
        _check_validity(cert, d / "cert.pem", now)
        if (d / "permissions.xml").is_file():
            end = _not_after(d / "permissions.xml")
            if end is not None and end <= now:
                raise KeystoreError(f"{d / 'permissions.xml'}: expired on {end:%Y-%m-%d}")
        if smime and _p7s_signed_by(d / "permissions.p7s", ca_path) is False:
            raise KeystoreError(f"{d / 'permissions.p7s'}: not signed by the keystore's CA")
        if grants is not None and enclave in grants:
            granted.append((d, grants[enclave]))
    for d, grant in granted:  # every enclave there first: a missing one is the plainer word
        _check_grant(keystore, d, grant)


def _check_grant(keystore: Path, d: Path, grant: Grant) -> None:
    """KeystoreError naming what ``grant`` needs that the enclave ``d``'s signed
    permissions do not allow."""
    p7s = d / "permissions.p7s"
    try:
        text = p7s.read_bytes()[:4 << 20].decode("utf-8", "replace")
    except OSError as exc:
        raise KeystoreError(f"{p7s}: cannot read it: {exc.strerror}") from None
    start, end = text.find("<?xml"), text.find("</dds>")
    if start < 0 or end < 0:
        raise KeystoreError(f"{p7s}: holds no permissions document")
    try:
        missing = lacking(grant, text[start:end + len("</dds>")])
    except ValueError as exc:
        raise KeystoreError(f"{p7s}: {exc}") from None
    if missing:
        more = f" and {len(missing) - 3} more" if len(missing) > 3 else ""
        raise KeystoreError(
            f"{p7s}: this run's {grant.enclave} needs what the permissions do not grant: "
            f"{', '.join(missing[:3])}{more} (a keystore made for another scenario or "
            f"plant: make this formation's with `formation-ilc keystore create {keystore} "
            f"SCENARIO`, --plant as the run's)")


def _check_validity(cert: x509.Certificate, path: Path, now: datetime) -> None:
    if cert.not_valid_after_utc <= now:
        raise KeystoreError(f"{path}: expired on {cert.not_valid_after_utc:%Y-%m-%d %H:%M} "
                            f"UTC (re-run `formation-ilc keystore create`)")
    if cert.not_valid_before_utc > now:
        raise KeystoreError(f"{path}: not valid before "
                            f"{cert.not_valid_before_utc:%Y-%m-%d %H:%M} UTC")
