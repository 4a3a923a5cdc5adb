"""rosbag2 Jazzy's reading of an MCAP file's ``rosbag2`` metadata record, rule for rule.

What ``ros2 bag info`` and ``ros2 bag play`` do on every read-only open
(``rosbag2_storage_mcap`` ``MCAPStorage::get_metadata`` -> ``read_metadata``): load the
record's ``serialized_metadata`` with yaml-cpp and decode it with
``YAML::convert<rosbag2_storage::BagMetadata>::decode`` (``rosbag2_storage/yaml.hpp``), the
QoS profiles with ``convert<rclcpp::QoS>::decode`` (``qos.cpp``); then every channel's
``offered_qos_profiles`` string with ``to_rclcpp_qos_vector`` at the record's version.
yaml-cpp keeps every scalar as text and converts it on ``as<T>()``; the port does the
same on PyYAML's node tree (``yaml.compose``), so a wrong type (a string where a sequence
goes, a negative count, a float) fails here as it throws there.

``decode_bag_metadata`` returns the decoded values (Python types) or raises
``BadConversion`` naming the field.
"""

from __future__ import annotations

import re
from typing import Any

import yaml
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode

__all__ = ["BadConversion", "decode_bag_metadata", "decode_qos_vector", "INFINITE"]

#: rmw's RMW_DURATION_INFINITE (rmw/time.h), as rosbag2 writes it
INFINITE = {"sec": 9223372036, "nsec": 854775807}
#: the Foxy-era "infinite" values rosbag2 translates to RMW_DURATION_INFINITE on decode
_FOXY_INFINITE = [(0x7FFFFFFFFFFFFFFF // 10**9, 0x7FFFFFFFFFFFFFFF % 10**9),
                  (0x7FFFFFFF, 0xFFFFFFFF), (0x7FFFFFFF, 0x7FFFFFFF)]

#: rmw_qos_*_policy_from_str (rmw/src/qos_string_conversions.c); anything else is UNKNOWN
_POLICIES = {
    "history": {"system_default", "keep_last", "keep_all"},
    "reliability": {"system_default", "reliable", "best_effort", "best_available"},
    "durability": {"system_default", "transient_local", "volatile", "best_available"},
    "liveliness": {"system_default", "automatic", "manual_by_topic", "best_available"},
}
#: RMW_QOS_POLICY_HISTORY_SYSTEM_DEFAULT .. RMW_QOS_POLICY_HISTORY_UNKNOWN
_HISTORY_INTS = range(0, 4)


class BadConversion(ValueError):
    """yaml-cpp's TypedBadConversion / InvalidNode: what rosbag2 throws on."""


def _at(node: Node | None, key: str, where: str) -> Node:
    """``node[key]`` that must exist (yaml-cpp: an undefined node throws on ``as``)."""
    if not isinstance(node, MappingNode):
        raise BadConversion(f"{where}: not a map")
    for k, v in node.value:
        if isinstance(k, ScalarNode) and k.value == key:
            return v
    raise BadConversion(f"{where}.{key}: missing")


def _scalar(node: Node, where: str) -> str:
    if isinstance(node, ScalarNode):
        return str(node.value)
    raise BadConversion(f"{where}: not a scalar")


def as_string(node: Node, where: str) -> str:
    # yaml-cpp: a null node reads as "null", a scalar as its text, anything else throws
    if isinstance(node, ScalarNode) and node.tag == "tag:yaml.org,2002:null" \
            and node.style is None and node.value in ("", "~", "null", "Null", "NULL"):
        return "null"
    return _scalar(node, where)


def _integer(node: Node, where: str, lo: int, hi: int) -> int:
    text = _scalar(node, where)  # quoted or not: yaml-cpp converts the text
    if not re.fullmatch(r"[+-]?[0-9]+", text):
        raise BadConversion(f"{where}: {text!r} is not an integer")
    if text.startswith("-") and lo == 0:
        raise BadConversion(f"{where}: {text!r} is negative (unsigned)")
    v = int(text)
    if not lo <= v <= hi:
        raise BadConversion(f"{where}: {v} out of range")
    return v


def as_int(node: Node, where: str) -> int:
    return _integer(node, where, -(2**31), 2**31 - 1)


def as_uint64(node: Node, where: str) -> int:
    return _integer(node, where, 0, 2**64 - 1)


_TRUE = {"y", "Y", "yes", "Yes", "YES", "true", "True", "TRUE", "on", "On", "ON"}
_FALSE = {"n", "N", "no", "No", "NO", "false", "False", "FALSE", "off", "Off", "OFF"}


def as_bool(node: Node, where: str) -> bool:
    text = _scalar(node, where)
    if text in _TRUE:
        return True
    if text in _FALSE:
        return False
    raise BadConversion(f"{where}: {text!r} is not a bool")


def _seq(node: Node, where: str) -> list[Node]:
    # the vector converters return false on anything but a sequence: decode_for_version throws
    if not isinstance(node, SequenceNode):
        raise BadConversion(f"{where}: not a sequence")
    return list(node.value)


def _policy(node: Node, name: str, where: str) -> str:
    text = _scalar(node, where)
    return text if text in _POLICIES[name] else "unknown"


def _time(node: Node, where: str) -> tuple[int, int]:
    t = (as_uint64(_at(node, "sec", where), f"{where}.sec"),
         as_uint64(_at(node, "nsec", where), f"{where}.nsec"))
    return (INFINITE["sec"], INFINITE["nsec"]) if t in _FOXY_INFINITE else t


def decode_qos(node: Node, where: str) -> dict[str, Any]:
    """``convert<rclcpp::QoS>::decode``: the version is detected from ``history``."""
    h = _at(node, "history", where)
    try:
        hi = as_int(h, where)
        legacy = hi in _HISTORY_INTS
    except BadConversion:
        legacy = False
    q: dict[str, Any] = {}
    if legacy:  # version <= 8: the policies are enum integers
        q["history"] = hi
        for p in ("reliability", "durability", "liveliness"):
            q[p] = as_int(_at(node, p, where), f"{where}.{p}")
    else:
        q["history"] = _policy(h, "history", f"{where}.history")
        for p in ("reliability", "durability", "liveliness"):
            q[p] = _policy(_at(node, p, where), p, f"{where}.{p}")
    if q["history"] in ("keep_last", 1):
        q["depth"] = as_int(_at(node, "depth", where), f"{where}.depth")
    for t in ("deadline", "lifespan", "liveliness_lease_duration"):
        q[t] = _time(_at(node, t, where), f"{where}.{t}")
    q["avoid_ros_namespace_conventions"] = as_bool(
        _at(node, "avoid_ros_namespace_conventions", where),
        f"{where}.avoid_ros_namespace_conventions")
    return q


def decode_qos_vector(node: Node, where: str) -> list[dict[str, Any]]:
    return [decode_qos(v, f"{where}[{i}]") for i, v in enumerate(_seq(node, where))]


def _topic(node: Node, version: int, where: str) -> dict[str, Any]:
    t: dict[str, Any] = {k: as_string(_at(node, k, where), f"{where}.{k}")
                         for k in ("name", "type", "serialization_format")}
    if version >= 9:
        t["offered_qos_profiles"] = decode_qos_vector(_at(node, "offered_qos_profiles", where),
                                                      f"{where}.offered_qos_profiles")
    elif version >= 4:
        text = as_string(_at(node, "offered_qos_profiles", where),
                         f"{where}.offered_qos_profiles")
        t["offered_qos_profiles"] = (decode_qos_vector(yaml.compose(text), where)
                                     if text else [])
    t["type_description_hash"] = (as_string(_at(node, "type_description_hash", where),
                                            f"{where}.type_description_hash")
                                  if version >= 7 else "")
    return t


def _nanoseconds(node: Node, key: str, where: str) -> int:
    return as_uint64(_at(node, key, where), f"{where}.{key}")


def decode_bag_metadata(serialized: str) -> dict[str, Any]:
    """``convert<BagMetadata>::decode`` of a ``serialized_metadata`` text."""
    root = yaml.compose(serialized)
    w = "serialized_metadata"
    m: dict[str, Any] = {"version": as_int(_at(root, "version", w), "version")}
    v = m["version"]
    m["storage_identifier"] = as_string(_at(root, "storage_identifier", w),
                                        "storage_identifier")
    m["duration"] = _nanoseconds(_at(root, "duration", w), "nanoseconds", "duration")
    m["starting_time"] = _nanoseconds(_at(root, "starting_time", w), "nanoseconds_since_epoch",
                                      "starting_time")
    m["message_count"] = as_uint64(_at(root, "message_count", w), "message_count")
    m["topics_with_message_count"] = [
        {"topic_metadata": _topic(_at(t, "topic_metadata", f"topics[{i}]"), v,
                                  f"topics[{i}].topic_metadata"),
         "message_count": as_uint64(_at(t, "message_count", f"topics[{i}]"),
                                    f"topics[{i}].message_count")}
        for i, t in enumerate(_seq(_at(root, "topics_with_message_count", w),
                                   "topics_with_message_count"))]
    m["relative_file_paths"] = [as_string(p, f"relative_file_paths[{i}]") for i, p in
                                enumerate(_seq(_at(root, "relative_file_paths", w),
                                               "relative_file_paths"))]
    if v >= 3:
        for k in ("compression_format", "compression_mode"):
            m[k] = as_string(_at(root, k, w), k)
    if v >= 5:
        m["files"] = [
            {"path": as_string(_at(f, "path", f"files[{i}]"), f"files[{i}].path"),
             "starting_time": _nanoseconds(_at(f, "starting_time", f"files[{i}]"),
                                           "nanoseconds_since_epoch",
                                           f"files[{i}].starting_time"),
             "duration": _nanoseconds(_at(f, "duration", f"files[{i}]"), "nanoseconds",
                                      f"files[{i}].duration"),
             "message_count": as_uint64(_at(f, "message_count", f"files[{i}]"),
                                        f"files[{i}].message_count")}
            for i, f in enumerate(_seq(_at(root, "files", w), "files"))]
    if v >= 6:
        node = _at(root, "custom_data", w)
        if isinstance(node, MappingNode):
            m["custom_data"] = {as_string(k, "custom_data"): as_string(x, "custom_data")
                                for k, x in node.value}
        elif as_string(node, "custom_data") == "null":  # iterating a null node: nothing
            m["custom_data"] = {}
        else:
            raise BadConversion("custom_data: not a map")
    if v >= 8:
        m["ros_distro"] = as_string(_at(root, "ros_distro", w), "ros_distro")
    return m


def channel_qos(text: str, version: int) -> list[dict[str, Any]]:
    """``to_rclcpp_qos_vector`` of a channel's ``offered_qos_profiles`` metadata string."""
    if not text:
        return []
    return decode_qos_vector(yaml.compose(text), "offered_qos_profiles")


def check_file(path: Any) -> dict[str, Any]:
    """The ``rosbag2`` record of a closed MCAP file as rosbag2 Jazzy reads it, checked
    against the file itself (its summary: channels, counts, span), then opened with
    ``rosbags``' reader as a bag folder whose metadata.yaml is that record. Returns the
    decoded record."""
    from pathlib import Path

    from mcap.reader import make_reader

    path = Path(path)
    with path.open("rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        records = [m for m in reader.iter_metadata() if m.name == "rosbag2"]
    assert summary is not None and summary.statistics is not None
    assert len(records) == 1, f"{len(records)} rosbag2 records"
    text = records[0].metadata["serialized_metadata"]
    bag = decode_bag_metadata(text)
    stats = summary.statistics
    assert bag["version"] == 9 and bag["ros_distro"] == "jazzy"
    assert bag["storage_identifier"] == "mcap"
    assert bag["compression_format"] == bag["compression_mode"] == ""
    assert bag["relative_file_paths"] == [path.name]
    assert bag["message_count"] == stats.message_count
    start = stats.message_start_time if stats.message_count else 0
    span = stats.message_end_time - start if stats.message_count else 0
    assert bag["starting_time"] == start and bag["duration"] == span
    assert bag["files"] == [{"path": path.name, "starting_time": start, "duration": span,
                             "message_count": stats.message_count}]
    by_topic = {t["topic_metadata"]["name"]: t for t in bag["topics_with_message_count"]}
    assert len(by_topic) == len(bag["topics_with_message_count"]) == len(summary.channels)
    for cid, ch in summary.channels.items():
        t = by_topic[ch.topic]
        meta = t["topic_metadata"]
        assert meta["type"] == summary.schemas[ch.schema_id].name
        assert meta["serialization_format"] == ch.message_encoding == "cdr"
        assert t["message_count"] == stats.channel_message_counts.get(cid, 0)
        assert meta["type_description_hash"] == ch.metadata.get("topic_type_hash", "")
        # the channel's own copy (what rosbag2 finally shows): the same profiles
        assert channel_qos(ch.metadata["offered_qos_profiles"], 9) == \
            meta["offered_qos_profiles"]
        assert meta["offered_qos_profiles"], ch.topic
    _open_with_rosbags(path, text, bag)
    return bag


def _open_with_rosbags(path: Any, text: str, bag: dict[str, Any]) -> None:
    import tempfile
    from pathlib import Path

    from rosbags.rosbag2 import Reader

    with tempfile.TemporaryDirectory() as d:
        folder = Path(d)
        (folder / path.name).symlink_to(Path(path).resolve())
        body = "".join(f"  {line}\n" for line in text.splitlines())
        (folder / "metadata.yaml").write_text(f"rosbag2_bagfile_information:\n{body}")
        with Reader(folder) as r:
            assert r.message_count == bag["message_count"]
            counts = {c.topic: c.msgcount for c in r.connections}
            assert counts == {t["topic_metadata"]["name"]: t["message_count"]
                              for t in bag["topics_with_message_count"]}
            for c in r.connections:
                assert c.ext.offered_qos_profiles, c.topic
                assert c.ext.offered_qos_profiles[0].reliability.name != "UNKNOWN"
            assert sum(1 for _ in r.messages()) == bag["message_count"]
