"""The SROS2 keystore (formation_ilc.store.keystore): layout, signatures, re-runs that reissue
only what changed, and the launcher's checks (missing, expired, foreign CA)."""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
import pytest
from cryptography import x509

from formation_ilc.store.keystore import (
    KeystoreError,
    create,
    enclave_dir,
    enclave_prefixes,
    verify,
)
from tests.config.test_enclaves import ADJ, LEADER, NS, grants_of

ROBOT2 = f"{NS}/robot_2"


def grants(adj=ADJ, leader=LEADER):
    return grants_of(adj, leader)


def four_robots():
    adj = np.zeros((4, 4))
    adj[:3, :3] = ADJ
    adj[3, 2] = 1.0
    return grants(adj, np.append(LEADER, 0.0))


def smime_content(p7s: Path, ca: Path) -> bytes:
    """The document a signed file carries, if it verifies against ``ca`` (openssl); S/MIME
    text is signed with CRLF line ends, as the verifier reads it."""
    out = subprocess.run(["openssl", "smime", "-verify", "-in", str(p7s), "-CAfile", str(ca),
                          "-purpose", "any", "-text"], capture_output=True, check=True)
    return out.stdout.replace(b"\r\n", b"\n")


def snapshot(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file()}


@pytest.fixture
def ks(tmp_path):
    path = tmp_path / "ks"
    done = create(path, grants())
    assert done.ca == "created"
    return path


def test_layout_is_sros2s(ks):
    for f in ("public/ca.cert.pem", "public/identity_ca.cert.pem",
              "public/permissions_ca.cert.pem", "private/ca.key.pem",
              "enclaves/governance.xml", "enclaves/governance.p7s"):
        assert (ks / f).is_file(), f
    d = enclave_dir(ks, ROBOT2)
    assert d == ks / "enclaves" / "formation" / "robot_2"
    for f in ("cert.pem", "key.pem", "permissions.xml", "permissions.p7s", "governance.p7s",
              "identity_ca.cert.pem", "permissions_ca.cert.pem"):
        assert (d / f).is_file() and not (d / f).is_symlink(), f
    for key in (ks / "private" / "ca.key.pem", d / "key.pem"):
        assert stat.S_IMODE(key.stat().st_mode) == 0o600
    assert len(list((ks / "enclaves" / "formation").iterdir())) == len(grants())


@pytest.mark.skipif(shutil.which("openssl") is None, reason="needs the openssl CLI")
def test_documents_are_smime_signed_by_the_ca(ks):
    ca = ks / "public" / "ca.cert.pem"
    d = enclave_dir(ks, ROBOT2)
    p7s = (d / "permissions.p7s").read_text()
    assert p7s.startswith("MIME-Version: 1.0") and "application/x-pkcs7-signature" in p7s
    assert smime_content(d / "permissions.p7s", ca) == (d / "permissions.xml").read_bytes()
    assert smime_content(ks / "enclaves/governance.p7s", ca) == \
        (ks / "enclaves/governance.xml").read_bytes()


def test_enclave_certificate(ks):
    ca = x509.load_pem_x509_certificate((ks / "public" / "ca.cert.pem").read_bytes())
    cert = x509.load_pem_x509_certificate((enclave_dir(ks, ROBOT2) / "cert.pem").read_bytes())
    cert.verify_directly_issued_by(ca)
    assert cert.subject.rfc4514_string() == f"CN={ROBOT2}"
    text = (enclave_dir(ks, ROBOT2) / "permissions.xml").read_text()
    assert f"<subject_name>CN={ROBOT2}</subject_name>" in text
    assert f"<not_after>{cert.not_valid_after_utc:%Y-%m-%dT%H:%M:%S}</not_after>" in text


def test_each_enclave_gives_the_guid_prefix_of_its_participants(ks):
    """What a node compares a shared topic's writers with under --secure
    (protocol.writers.WriterTable.enclaves): the prefix Fast DDS derives from the subject
    as the certificate carries it (OpenSSL hashes the name's DER as encoded there)."""
    from formation_ilc.protocol.writers import enclave_prefix

    got = enclave_prefixes(ks, NS)
    assert set(got) == {f"{NS}/{d.name}" for d in (ks / "enclaves" / "formation").iterdir()}
    cert = x509.load_pem_x509_certificate((enclave_dir(ks, ROBOT2) / "cert.pem").read_bytes())
    der = cert.subject.public_bytes()
    assert der in cert.tbs_certificate_bytes
    assert got[ROBOT2] == enclave_prefix(der)
    assert len(set(got.values())) == len(got)  # one participant prefix an enclave
    assert enclave_prefixes(ks, "/elsewhere") == {}


def test_rerun_changes_nothing(ks):
    before = snapshot(ks)
    done = create(ks, grants())
    assert set(done.enclaves.values()) == {"unchanged"} and done.governance == "unchanged"
    assert snapshot(ks) == before


def test_a_robot_added_reissues_only_what_changed(ks):
    before = snapshot(ks)
    done = create(ks, four_robots())
    changed = {p for p, a in done.enclaves.items() if a != "unchanged"}
    # robot 4 reads robot 3; the plant, links, recorder, monitor and live view see robot 4,
    # and robots 1 to 3 read its pose (their safety filters keep away from every robot;
    # robot 3 also answers robot 4's clock questions)
    assert changed == {f"{NS}/robot_4", f"{NS}/robot_sim", f"{NS}/link_emulator",
                       f"{NS}/recorder", f"{NS}/monitor", f"{NS}/liveview",
                       f"{NS}/robot_1", f"{NS}/robot_2", f"{NS}/robot_3"}
    assert done.enclaves[f"{NS}/robot_1"] == "permissions signed"
    assert done.enclaves[f"{NS}/robot_4"] == "new identity, permissions signed"
    assert done.enclaves[f"{NS}/robot_sim"] == "permissions signed"
    after = snapshot(ks)
    for rel, data in before.items():
        kept = not any(f"/{name}/" in rel for name in ("robot_sim", "link_emulator",
                                                        "recorder", "monitor", "liveview",
                                                        "robot_1", "robot_2", "robot_3"))
        if kept or rel.endswith(("cert.pem", "key.pem")):
            assert after[rel] == data, rel  # identities are kept


def test_a_robot_removed_loses_its_enclave(ks):
    create(ks, four_robots())
    done = create(ks, grants())
    assert done.enclaves[f"{NS}/robot_4"].startswith("removed")
    assert not enclave_dir(ks, f"{NS}/robot_4").exists()


def test_verify_accepts_a_fresh_keystore(ks):
    verify(ks, list(grants()))


def test_verify_missing_keystore(tmp_path):
    with pytest.raises(KeystoreError, match=r"nope: no such keystore folder"):
        verify(tmp_path / "nope", [ROBOT2])


def test_verify_missing_enclave(ks):
    with pytest.raises(KeystoreError, match=r"robot_9: missing: no enclave for node "):
        verify(ks, [*grants(), f"{NS}/robot_9"])
    (enclave_dir(ks, ROBOT2) / "key.pem").unlink()
    with pytest.raises(KeystoreError, match=r"robot_2/key.pem: missing"):
        verify(ks, [ROBOT2])


def test_verify_expired(tmp_path):
    ks = tmp_path / "old"
    create(ks, grants(), days=1, now=datetime.now(UTC) - timedelta(days=3))
    with pytest.raises(KeystoreError, match=r"cert.pem: expired on "):
        verify(ks, [ROBOT2])


def test_verify_not_yet_valid(tmp_path):
    ks = tmp_path / "future"
    create(ks, grants(), now=datetime.now(UTC) + timedelta(days=2))
    with pytest.raises(KeystoreError, match=r"ca.cert.pem: not valid before"):
        verify(ks, [ROBOT2])


def test_verify_foreign_ca(ks, tmp_path):
    other = tmp_path / "other"
    create(other, grants())
    # an enclave of another keystore copied in whole: its CA copies name the other CA
    shutil.rmtree(enclave_dir(ks, ROBOT2))
    shutil.copytree(enclave_dir(other, ROBOT2), enclave_dir(ks, ROBOT2))
    with pytest.raises(KeystoreError, match=r"robot_2/identity_ca.cert.pem: another CA"):
        verify(ks, [ROBOT2])
    # and with this keystore's CA copies beside it, the certificate still is not ours
    for name in ("identity_ca.cert.pem", "permissions_ca.cert.pem"):
        shutil.copy(ks / "public" / "ca.cert.pem", enclave_dir(ks, ROBOT2) / name)
    with pytest.raises(KeystoreError, match=r"robot_2/cert.pem: not issued by the keystore"):
        verify(ks, [ROBOT2])


@pytest.mark.skipif(shutil.which("openssl") is None, reason="needs the openssl CLI")
def test_verify_permissions_signed_by_another_ca(ks, tmp_path):
    other = tmp_path / "other"
    create(other, grants())
    shutil.copy(enclave_dir(other, ROBOT2) / "permissions.p7s",
                enclave_dir(ks, ROBOT2) / "permissions.p7s")
    with pytest.raises(KeystoreError, match=r"robot_2/permissions.p7s: not signed by the "):
        verify(ks, [ROBOT2])


def test_ca_key_must_match(ks, tmp_path):
    other = tmp_path / "other"
    create(other, grants())
    shutil.copy(other / "private" / "ca.key.pem", ks / "private" / "ca.key.pem")
    with pytest.raises(KeystoreError, match=r"ca.key.pem: not the key of "):
        create(ks, grants())


def test_days_must_be_positive(tmp_path):
    with pytest.raises(KeystoreError, match="--days"):
        create(tmp_path / "ks", grants(), days=0)
    assert not (tmp_path / "ks").exists() or not os.listdir(tmp_path / "ks")
