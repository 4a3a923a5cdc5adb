"""DDS-Security permissions and governance of a formation's enclaves.

A secure formation (``formation-ilc keystore``, ``launch --secure``) runs each node in an
SROS2 enclave whose signed permissions list the topics it may publish and subscribe; with
``Enforce`` Fast DDS refuses any other writer or reader at creation, and its peers refuse
a participant without a certificate of the formation's CA. What each node may do is its
member's in the roster (``formation_ilc.config.roster``: ``Roster.grants``, least privilege
derived from the graph); this module turns a :class:`Grant` into the permissions document
(every node also gets its ROS housekeeping: ``rosout``, ``parameter_events``, its own
parameter and type-description services, and ``ros_discovery_info``) and writes the
governance. It is pure: grants and XML text; ``formation_ilc.store.keystore`` signs and
writes them.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from datetime import datetime
from xml.sax.saxutils import escape

__all__ = ["Grant", "enclave_path", "enclave_prefix", "driver_enclave",
           "dds_topic", "housekeeping", "permissions_xml", "governance_xml", "DOMAIN_MAX",
           "grant_topics", "permitted_topics", "lacking"]

#: the ROS domain ids a keystore serves (every id ROS 2 allows on Linux)
DOMAIN_MAX = 232
#: services every rclpy node offers under its own name
_NODE_SERVICES = ("describe_parameters", "get_parameter_types", "get_parameters",
                  "list_parameters", "set_parameters", "set_parameters_atomically",
                  "get_type_description")


@dataclass(frozen=True)
class Grant:
    """What one node may do: its enclave, its node name and namespace, and the ROS topic
    names (absolute) it may publish and subscribe; services as DDS names (rq/, rr/)."""

    enclave: str
    node: str
    node_namespace: str
    publish: tuple[str, ...]
    subscribe: tuple[str, ...]
    dds_publish: tuple[str, ...] = ()
    dds_subscribe: tuple[str, ...] = ()
    #: the node name its ROS housekeeping (services) runs under; ``*``: any node in
    #: ``node_namespace`` (a driver whose node name is the driver's own)
    service_node: str = ""


#: robot i's driver runs in this enclave (its node name is the driver's own)
DRIVER_ENCLAVE_PREFIX = "driver_"


def driver_enclave(i: int) -> str:
    """The enclave of robot ``i``'s driver: ``driver_i`` (a real driver's, or the fake
    one's, whatever its node name)."""
    return f"{DRIVER_ENCLAVE_PREFIX}{int(i)}"


def enclave_path(namespace: str, name: str) -> str:
    """``/formation/robot_1``: the enclave of node ``name`` of the formation in
    ``namespace``."""
    return f"{namespace.rstrip('/')}/{name}"


def enclave_prefix(subject_der: bytes) -> bytes:
    """The first 6 bytes of the GUID prefix of every DDS-Security participant whose
    certificate has the subject ``subject_der`` (the DER of its X.509 name): a 1 bit, then
    the first 47 bits of the name's SHA-256. DDS-Security 1.1, 9.3.3; Fast DDS sets them
    so (PKIDH ``adjust_participant_key``), and a handshake with a participant whose GUID
    does not carry its certificate's bits fails (PKIDH: "Bad participant_key's 47bits"):
    under ``--secure`` they name the participant's enclave, authenticated."""
    md = hashlib.sha256(subject_der).digest()
    out = [0x80 | (md[0] >> 1)]
    out += [((md[i - 1] << 7) | (md[i] >> 1)) & 0xFF for i in range(1, 6)]
    return bytes(out)


def dds_topic(ros_name: str) -> str:
    """The DDS topic of an absolute ROS topic name: ``/a/b`` -> ``rt/a/b``."""
    if not ros_name.startswith("/"):
        raise ValueError(f"not an absolute ROS topic name: {ros_name!r}")
    return "rt" + ros_name


def housekeeping(node_namespace: str, node: str) -> tuple[list[str], list[str]]:
    """(publish, subscribe) DDS topics of any rclpy node ``node`` in ``node_namespace``:
    rosout, parameter events, its own services, the ROS graph's discovery topic."""
    fq = f"{node_namespace.rstrip('/')}/{node}"
    pub = ["rt/rosout", "rt/parameter_events", "ros_discovery_info"]
    pub += [f"rr{fq}/{s}Reply" for s in _NODE_SERVICES]
    sub = ["rt/parameter_events", "ros_discovery_info"]
    sub += [f"rq{fq}/{s}Request" for s in _NODE_SERVICES]
    return pub, sub


def _stamp(t: datetime) -> str:
    return t.strftime("%Y-%m-%dT%H:%M:%S")


def grant_topics(grant: Grant) -> tuple[list[str], list[str]]:
    """(publish, subscribe): the DDS topics ``grant``'s permissions allow."""
    hk_pub, hk_sub = housekeeping(grant.node_namespace, grant.service_node or grant.node)
    pub = [dds_topic(x) for x in grant.publish] + list(grant.dds_publish) + hk_pub
    sub = [dds_topic(x) for x in grant.subscribe] + list(grant.dds_subscribe) + hk_sub
    return pub, sub


def permitted_topics(xml: str) -> tuple[set[str], set[str]]:
    """(publish, subscribe): the DDS topics a permissions document allows (every grant's
    allow rules); ValueError if it is not one."""
    import xml.etree.ElementTree as ET

    try:
        root = ET.fromstring(xml)
    except ET.ParseError as exc:
        raise ValueError(f"not a permissions document: {exc}") from None
    out: tuple[set[str], set[str]] = (set(), set())
    for rule in root.iter("allow_rule"):
        for i, kind in enumerate(("publish", "subscribe")):
            for part in rule.iter(kind):
                out[i].update((t.text or "").strip() for t in part.iter("topic"))
    return out


def lacking(grant: Grant, xml: str) -> list[str]:
    """What ``grant`` needs that the permissions document ``xml`` does not allow: one
    phrase a topic ("publish rt/formation/robot_3/cmd_vel"), sorted. A permitted topic
    may be a pattern (DDS-Security's fnmatch)."""
    from fnmatch import fnmatchcase

    pub, sub = grant_topics(grant)
    have = permitted_topics(xml)

    def allowed(topic: str, patterns: set[str]) -> bool:
        return topic in patterns or any(fnmatchcase(topic, p) for p in patterns)

    return ([f"{kind} {t}" for kind, need, pats in (("publish", pub, have[0]),
                                                     ("subscribe", sub, have[1]))
             for t in sorted(set(need)) if not allowed(t, pats)])


def permissions_xml(grant: Grant, subject: str, not_before: datetime, not_after: datetime
                    ) -> str:
    """The DDS-Security permissions document of one enclave (default DENY).

    ``subject`` is the identity certificate's subject (RFC 4514, e.g. ``CN=/formation/
    robot_1``); the validity is the certificate's, in UTC.
    """
    pub, sub = grant_topics(grant)

    def topics(names: list[str]) -> str:
        return "".join(f"\n            <topic>{escape(x)}</topic>"
                       for x in sorted(set(names)))

    return f"""<?xml version="1.0" encoding="UTF-8"?>
<dds xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" \
xsi:noNamespaceSchemaLocation="http://www.omg.org/spec/DDS-SECURITY/20170901/\
omg_shared_ca_permissions.xsd">
  <permissions>
    <grant name="{escape(grant.enclave)}">
      <subject_name>{escape(subject)}</subject_name>
      <validity>
        <not_before>{_stamp(not_before)}</not_before>
        <not_after>{_stamp(not_after)}</not_after>
      </validity>
      <allow_rule>
        <domains>
          <id_range>
            <min>0</min>
            <max>{DOMAIN_MAX}</max>
          </id_range>
        </domains>
        <publish>
          <topics>{topics(pub)}
          </topics>
        </publish>
        <subscribe>
          <topics>{topics(sub)}
          </topics>
        </subscribe>
      </allow_rule>
      <default>DENY</default>
    </grant>
  </permissions>
</dds>
"""


def governance_xml() -> str:
    """The formation's governance: authenticated participants only, every reader and
    writer checked against the permissions, and every RTPS message between participants
    encrypted, with a MAC for each receiver (``ENCRYPT_WITH_ORIGIN_AUTHENTICATION``: a
    participant cannot pass off a message as another's). Discovery and liveliness travel
    in those encrypted messages, without a second, submessage layer of their own
    (``discovery_protection_kind`` and ``liveliness_protection_kind`` NONE): that layer
    keyed each of the eight secure builtin endpoints separately, one more key exchange per
    endpoint and pair of participants, each sent to every participant, and kept a 24-robot
    team at 40 s to start (22-31 s without); every member of the formation reads discovery
    anyway, and to an outsider it is as encrypted as before.

    The encryption is per message, not per topic (``data_protection_kind`` NONE): per-topic
    keys are exchanged for every matched reader and writer (over two thousand exchanges in
    a 24-robot team, each sent to every participant), and such a team on two cores never
    finished them; with per-message keys, one exchange per pair of participants, it starts
    (docs/security.md). What it gives up: a team member that captures traffic not meant for
    it can decrypt it (its permissions still keep it from reading or writing the topic)."""
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<dds xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" \
xsi:noNamespaceSchemaLocation="http://www.omg.org/spec/DDS-SECURITY/20170901/\
omg_shared_ca_governance.xsd">
  <domain_access_rules>
    <domain_rule>
      <domains>
        <id_range>
          <min>0</min>
          <max>{DOMAIN_MAX}</max>
        </id_range>
      </domains>
      <allow_unauthenticated_participants>false</allow_unauthenticated_participants>
      <enable_join_access_control>true</enable_join_access_control>
      <discovery_protection_kind>NONE</discovery_protection_kind>
      <liveliness_protection_kind>NONE</liveliness_protection_kind>
      <rtps_protection_kind>ENCRYPT_WITH_ORIGIN_AUTHENTICATION</rtps_protection_kind>
      <topic_access_rules>
        <topic_rule>
          <topic_expression>*</topic_expression>
          <enable_discovery_protection>false</enable_discovery_protection>
          <enable_liveliness_protection>false</enable_liveliness_protection>
          <enable_read_access_control>true</enable_read_access_control>
          <enable_write_access_control>true</enable_write_access_control>
          <metadata_protection_kind>NONE</metadata_protection_kind>
          <data_protection_kind>NONE</data_protection_kind>
        </topic_rule>
      </topic_access_rules>
    </domain_rule>
  </domain_access_rules>
</dds>
"""
