"""The secure run's start-up guard (formation_ilc.system.securedds): a Fast DDS without the
security plugins, the wheels' build, is refused, also under a rebuilt rmw (where it would
otherwise run with no security at all), and a secure launch stops before any node starts."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from formation_ilc.system.securedds import (
    INSECURE_RMW_MARKER,
    SECURITY_MARKER,
    has_marker,
    loaded_libraries,
)

VENV_LIB = Path(sys.prefix) / "lib"
#: where scripts/build_secure_dds.sh keeps the wheels' files it replaced
WHEEL_BACKUP = VENV_LIB / "formation-ilc-wheel-dds"


def wheel_fastdds() -> Path:
    """The wheels' libfastrtps: the venv's own, or the build script's copy of it."""
    for path in (VENV_LIB / "libfastrtps.so.2.14.5", WHEEL_BACKUP / "libfastrtps.so.2.14.5"):
        if path.is_file() and not has_marker(path, SECURITY_MARKER):
            return path
    pytest.fail(f"no Fast DDS of the wheels in {VENV_LIB} or {WHEEL_BACKUP}")


def with_wheel_fastdds(tmp_path: Path) -> dict[str, str]:
    """An environment whose loader finds the wheels' libfastrtps before any other."""
    d = tmp_path / "wheel-lib"
    d.mkdir()
    # a copy, not a link: the loader's map then names this folder, proving it was used
    shutil.copy(wheel_fastdds(), d / "libfastrtps.so.2.14")
    env = dict(os.environ)
    # the wheels' bootstrapper would rebuild LD_LIBRARY_PATH (in no fixed order); this one
    # is complete: ours first, then what this process was started with
    env["_ROS_WHEELS_BOOTSTRAP_COMPLETE"] = "1"
    env["LD_LIBRARY_PATH"] = f"{d}:{os.environ.get('LD_LIBRARY_PATH', '')}"
    return env


def test_loaded_libraries_are_the_venvs():
    out = subprocess.run([sys.executable, "-c",
                          "from formation_ilc.system.securedds import loaded_libraries as f;"
                          "l = f(); print(l.fastdds); print(l.rmw_shared); print(l.rmw)"],
                         capture_output=True, text=True, check=True)
    paths = [Path(p) for p in out.stdout.split()]
    assert [p.name for p in paths] == ["libfastrtps.so.2.14", "librmw_fastrtps_shared_cpp.so",
                                       "librmw_fastrtps_cpp.so"]
    assert all(p.is_file() for p in paths)
    assert callable(loaded_libraries)


def test_guard_refuses_the_wheels_fastdds(tmp_path):
    env = with_wheel_fastdds(tmp_path)
    out = subprocess.run([sys.executable, "-m", "formation_ilc.system.securedds"], env=env,
                         capture_output=True, text=True)
    assert out.returncode == 2, out.stdout + out.stderr
    line = out.stderr.strip()
    assert "\n" not in line
    assert str(tmp_path / "wheel-lib" / "libfastrtps.so.2.14") in line
    assert "without the DDS-Security plugins" in line
    assert "scripts/build_secure_dds.sh" in line


def test_the_wheels_rmw_is_not_built_for_security():
    # the refusal text is what tells a wheel's rmw from a rebuilt one
    wheel_rmw = [p for p in (VENV_LIB / "librmw_fastrtps_shared_cpp.so",
                             WHEEL_BACKUP / "librmw_fastrtps_shared_cpp.so")
                 if p.is_file() and has_marker(p, INSECURE_RMW_MARKER)]
    assert wheel_rmw, "no rmw_fastrtps of the wheels found"


def test_secure_launch_refuses_the_wheels_fastdds_before_any_node(tmp_path):
    ks = tmp_path / "ks"
    made = subprocess.run([sys.executable, "-m", "formation_ilc.cli", "keystore", "create",
                           str(ks), "paper-triangle3"], capture_output=True, text=True)
    assert made.returncode == 0, made.stderr
    env = with_wheel_fastdds(tmp_path)
    out = tmp_path / "run"
    res = subprocess.run([sys.executable, "-m", "formation_ilc.cli", "launch",
                          "paper-triangle3", "--trials", "2", "--out", str(out), "--no-plots",
                          "--secure", str(ks)], env=env, capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 2, res.stdout + res.stderr
    assert res.stderr.count("\n") == 1 and res.stderr.startswith("error: --secure: ")
    assert "libfastrtps.so.2.14" in res.stderr and "build_secure_dds.sh" in res.stderr
    assert not (out / "logs").exists()  # no node was started


def test_maps_parsing_and_markers(tmp_path):
    from formation_ilc.system.securedds import _mapped

    maps = ("7f00-7f01 r-xp 00000000 08:01 12 /opt/x/lib/libfastrtps.so.2.14\n"
            "7f02-7f03 r--p 00000000 00:00 0 \n"
            "7f04-7f05 r-xp 00000000 08:01 13 /opt/x/lib/librmw_fastrtps_cpp.so\n")
    assert _mapped(maps, "libfastrtps.so") == Path("/opt/x/lib/libfastrtps.so.2.14")
    assert _mapped(maps, "librmw_fastrtps_shared_cpp.so") is None
    lib = tmp_path / "lib.so"
    lib.write_bytes(b"\0" * 4096 + SECURITY_MARKER + b"\0" * 10)
    assert has_marker(lib, SECURITY_MARKER) and not has_marker(lib, INSECURE_RMW_MARKER)


def test_the_secure_profile_retries_the_handshake_and_keeps_what_it_is_given(tmp_path):
    """The handshake properties go into the default participant profile: a fresh one, or
    the given file's, whose own profiles and values stay."""
    import xml.etree.ElementTree as ET

    from formation_ilc.system.netns import lossy_profile
    from formation_ilc.system.securedds import HANDSHAKE_PROPERTIES, PROFILES_NS, secure_profile

    ns = {"p": PROFILES_NS}

    def props(text: str) -> dict[str, str]:
        root = ET.fromstring(text.split("\n", 2)[2])
        parts = [p for p in root.iter(f"{{{PROFILES_NS}}}participant")
                 if p.get("is_default_profile") == "true"]
        assert len(parts) == 1
        return {p.findtext("p:name", namespaces=ns): p.findtext("p:value", namespaces=ns)
                for p in parts[0].findall("p:rtps/p:propertiesPolicy/p:properties/p:property",
                                          ns)}

    assert props(secure_profile()) == dict(HANDSHAKE_PROPERTIES)
    lossy = secure_profile(lossy_profile())
    assert props(lossy) == dict(HANDSHAKE_PROPERTIES)
    assert "formation_ilc_lossy_links_writer" in lossy and "50000000" in lossy
    own = tmp_path / "own.xml"
    own.write_text(f"""<dds><profiles xmlns="{PROFILES_NS}">
  <participant profile_name="p" is_default_profile="true"><rtps><name>x</name>
    <propertiesPolicy><properties><property>
      <name>dds.sec.auth.builtin.PKI-DH.initial_handshake_resend_period</name>
      <value>300</value></property></properties></propertiesPolicy></rtps></participant>
</profiles></dds>""")
    mine = props(secure_profile(own))
    assert mine["dds.sec.auth.builtin.PKI-DH.initial_handshake_resend_period"] == "300"
    assert mine["dds.sec.auth.builtin.PKI-DH.max_handshake_requests"] == "1000000"
    bad = tmp_path / "bad.xml"
    bad.write_text("<nothing/>")
    with pytest.raises(ValueError, match="no <profiles>"):
        secure_profile(bad)
    with pytest.raises(ValueError, match="not a readable"):
        secure_profile(tmp_path / "missing.xml")
