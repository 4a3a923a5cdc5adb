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
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

from formation_ilc.system.ddsxml import Profiles, child

__all__ = ["RMW_PEER_IDS", "MARGIN", "MAX_IDS", "discovery_port", "peer_ids", "needs_peers",
           "peers_profile"]

#: participant ids that rmw_fastrtps's LOCALHOST peer reaches (its maxInitialPeersRange)
RMW_PEER_IDS = 32
#: ids beyond a run's own participants: others on the same domain and host (a user's
#: tools, a run being stopped) take the lowest free ids first
MARGIN = 16
#: participant ids of one domain: ids from 120 on share ports with the next domain
#: (RTPS port mapping: 7400 + 250 domain + 10 + 2 id)
MAX_IDS = 120


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


def peers_profile(base: Path | None, domain: int, participants: int) -> str:
    """A Fast DDS profiles file: ``base``'s profiles (or none) with 127.0.0.1 initial peers
    at the discovery ports of participant ids 0 .. peer_ids(participants) - 1 on
    ``domain``, added to the default participant profile's. ValueError names a ``base``
    that is not a profiles file."""
    doc = Profiles(base)
    ns = doc.ns
    part = doc.default_participant("formation_ilc_discovery")
    peers = child(child(child(part, "rtps", ns), "builtin", ns), "initialPeersList", ns)
    for i in range(peer_ids(participants)):
        udp = ET.SubElement(ET.SubElement(peers, f"{ns}locator"), f"{ns}udpv4")
        ET.SubElement(udp, f"{ns}address").text = "127.0.0.1"
        ET.SubElement(udp, f"{ns}port").text = str(discovery_port(domain, i))
    return doc.text(f"formation-ilc launch: every participant of a {participants}-process "
                    f"team on ROS_DOMAIN_ID={domain} announces itself to every other on "
                    f"this machine (formation_ilc/system/discovery.py)")
