"""Is the Fast DDS a node would load built with DDS-Security? The secure run's start-up guard.

The ROS 2 Jazzy wheels ship Fast DDS with ``SECURITY=OFF``; ``scripts/build_secure_dds.sh``
puts a secure build and the two rmw_fastrtps libraries rebuilt against it into the venv.
A later ``pip install`` can silently put the wheel's ``libfastrtps`` back. The rebuilt rmw
then starts with ``ROS_SECURITY_ENABLE=true`` and ``Enforce`` and runs with no security at
all (plaintext; an unsecured listener receives everything): it fails open. A secure run
therefore checks, before any node starts, what the dynamic loader really gives a node:

1. it loads ``librmw_fastrtps_cpp.so`` as rmw_implementation does (by name, through the
   ``LD_LIBRARY_PATH`` that the wheels' bootstrapper sets), and reads from
   ``/proc/self/maps`` which ``libfastrtps`` and ``librmw_fastrtps_shared_cpp`` came with it;
2. that ``libfastrtps`` must contain the builtin security plugins (the factory's name of
   the authentication plugin, ``builtin.PKI-DH``, is compiled in only with security);
3. that ``librmw_fastrtps_shared_cpp`` must have been built against a secure Fast DDS (a
   build without security carries its refusal text instead).

Any failure is :class:`InsecureDds`, whose message names the library and the command that
builds the secure one. ``python -m formation_ilc.system.securedds`` runs the check (exit 0
or 2); ``--expect DIR`` also requires the loaded libraries to be the files in ``DIR`` and
the rmw to be the patched one (the build script's own verification).

A secure run also gives every node the Fast DDS profile of :func:`secure_profile`: the
authentication handshake retried every second until it succeeds. With Fast DDS's defaults
a pair of participants gives up after 10 requests (about 14 s), silently, and 28
participants starting on two busy cores never all authenticate. Upstream rmw_fastrtps drops
a secure participant's profile properties; the build script's patched rmw keeps them
(:data:`PROFILE_MARKER`, :func:`keeps_profile_properties`).
"""

from __future__ import annotations

import argparse
import ctypes
import hashlib
import mmap
import sys
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

from formation_ilc.system.ddsxml import PROFILES_NS, Profiles, child

__all__ = ["BUILD_COMMAND", "SECURITY_MARKER", "INSECURE_RMW_MARKER", "PROFILE_MARKER",
           "HANDSHAKE_PROPERTIES", "InsecureDds", "LoadedDds", "has_marker",
           "loaded_libraries", "check", "keeps_profile_properties", "secure_profile", "main",
           "PROFILES_NS"]

#: how a user gets a secure Fast DDS into the active venv
BUILD_COMMAND = "bash scripts/build_secure_dds.sh (docs/security.md)"
#: in libfastrtps only when built with -DSECURITY=ON (SecurityPluginFactory)
SECURITY_MARKER = b"builtin.PKI-DH"
#: in librmw_fastrtps_shared_cpp only when built against a Fast DDS without security
INSECURE_RMW_MARKER = b"This Fast DDS version doesn't have the security libraries"
#: in librmw_fastrtps_shared_cpp only when built with the build script's patch
#: (scripts/secure_dds/rmw-keep-profile-properties.patch), which keeps a secure
#: participant's XML-profile properties
PROFILE_MARKER = b"formation-ilc: rmw keeps the XML profile's participant properties"
#: the PKI-DH handshake of every secure participant: a request every second, never given up
#: (Fast DDS: 10 requests from 125 ms, 1.5 times longer each, then silent failure)
HANDSHAKE_PROPERTIES = (
    ("dds.sec.auth.builtin.PKI-DH.max_handshake_requests", "1000000"),
    ("dds.sec.auth.builtin.PKI-DH.initial_handshake_resend_period", "1000"),
    ("dds.sec.auth.builtin.PKI-DH.handshake_resend_period_gain", "1.0"),
)
#: what rmw_implementation loads for RMW_IMPLEMENTATION=rmw_fastrtps_cpp
RMW_LIBRARY = "librmw_fastrtps_cpp.so"


class InsecureDds(RuntimeError):
    """The Fast DDS a node would load cannot run a secure formation (one-line message)."""


@dataclass(frozen=True)
class LoadedDds:
    """The libraries a node loads: Fast DDS and the two rmw_fastrtps libraries."""

    fastdds: Path
    rmw_shared: Path
    rmw: Path


def has_marker(path: Path, marker: bytes) -> bool:
    """Whether the file at ``path`` contains ``marker`` (read through a memory map)."""
    with open(path, "rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as mm:
        return mm.find(marker) >= 0


def _mapped(maps: str, stem: str) -> Path | None:
    """The first file in ``maps`` (``/proc/PID/maps`` text) whose name starts with ``stem``."""
    for line in maps.splitlines():
        parts = line.split(maxsplit=5)
        if len(parts) == 6 and Path(parts[5]).name.startswith(stem):
            return Path(parts[5].strip())
    return None


def loaded_libraries(rmw_library: str = RMW_LIBRARY) -> LoadedDds:
    """Load ``rmw_library`` by name, as a node does, and return what the loader mapped."""
    try:
        ctypes.CDLL(rmw_library, mode=ctypes.RTLD_LOCAL)
    except OSError as exc:
        raise InsecureDds(f"{rmw_library}: cannot load ({exc}); is this the project's venv "
                          f"with the ROS 2 wheels?") from None
    maps = Path("/proc/self/maps").read_text()
    found = {stem: _mapped(maps, stem) for stem in
             ("libfastrtps.so", "librmw_fastrtps_shared_cpp.so", "librmw_fastrtps_cpp.so")}
    missing = [stem for stem, path in found.items() if path is None]
    if missing:
        raise InsecureDds(f"{rmw_library}: loaded, but {', '.join(missing)} not mapped")
    return LoadedDds(*(p for p in found.values() if p is not None))


def check(rmw_library: str = RMW_LIBRARY) -> LoadedDds:
    """The libraries a node would load, if they can run secure nodes; else InsecureDds."""
    libs = loaded_libraries(rmw_library)
    if not has_marker(libs.fastdds, SECURITY_MARKER):
        raise InsecureDds(f"{libs.fastdds}: Fast DDS without the DDS-Security plugins (the "
                          f"wheel's build?): a secure run would run insecure; refusing. "
                          f"Build it into this venv: {BUILD_COMMAND}")
    if has_marker(libs.rmw_shared, INSECURE_RMW_MARKER):
        raise InsecureDds(f"{libs.rmw_shared}: rmw_fastrtps built against a Fast DDS "
                          f"without security; refusing. Build both into this venv: "
                          f"{BUILD_COMMAND}")
    return libs


def keeps_profile_properties(libs: LoadedDds) -> bool:
    """Whether the loaded rmw gives a secure participant its profile's properties (the
    handshake settings of :func:`secure_profile`): the build script's patched rmw."""
    return has_marker(libs.rmw_shared, PROFILE_MARKER)


def secure_profile(base: Path | None = None) -> str:
    """A Fast DDS XML profiles file for a secure run's processes: ``base``'s profiles (the
    user's FASTRTPS_DEFAULT_PROFILES_FILE, the lossy-links one, or none) with
    :data:`HANDSHAKE_PROPERTIES` in the default participant profile; a property ``base``
    sets itself keeps ``base``'s value. ValueError names a ``base`` that is not a profiles
    file."""
    doc = Profiles(base)
    ns = doc.ns
    part = doc.default_participant("formation_ilc_secure")
    props = child(child(child(part, "rtps", ns), "propertiesPolicy", ns), "properties", ns)
    have = {(p.findtext(f"{ns}name") or "").strip() for p in props}
    for name, value in HANDSHAKE_PROPERTIES:
        if name not in have:
            prop = ET.SubElement(props, f"{ns}property")
            ET.SubElement(prop, f"{ns}name").text = name
            ET.SubElement(prop, f"{ns}value").text = value
    return doc.text("formation-ilc launch --secure: the authentication handshake retried "
                    "every second until it succeeds (docs/security.md)")


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m formation_ilc.system.securedds",
        description="Check that the Fast DDS a node loads has DDS-Security (exit 0, else 2).")
    p.add_argument("--expect", type=Path, metavar="DIR",
                   help="also require the loaded libraries to equal DIR's files (a build's "
                        "lib/ folder)")
    args = p.parse_args(argv)
    try:
        libs = check()
        if args.expect is not None:
            for loaded in (libs.fastdds, libs.rmw_shared, libs.rmw):
                name = ("libfastrtps.so.2.14.5" if loaded.name.startswith("libfastrtps")
                        else loaded.name)
                want = args.expect / name
                if not want.is_file() or _sha256(want) != _sha256(loaded):
                    raise InsecureDds(f"{loaded}: not the build in {args.expect} (another "
                                      f"library on LD_LIBRARY_PATH first?)")
            if not keeps_profile_properties(libs):
                raise InsecureDds(f"{libs.rmw_shared}: not patched to keep a participant's "
                                  f"profile properties (rmw-keep-profile-properties.patch)")
    except InsecureDds as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"DDS-Security: {libs.fastdds} with {libs.rmw_shared.name} and {libs.rmw.name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
