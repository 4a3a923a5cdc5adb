"""Writing MCAP files as ROS 2 tools write them (profile ``ros2``), without rclpy.

* ``message_definition``: the full ``ros2msg`` text of a type with its dependencies, read
  from the installed ``.msg`` files, concatenated as rosbag2 does; ``type_hash``: its RIHS01
  hash (both with rosbags' .msg parser).
* ``qos_yaml``: a channel's ``offered_qos_profiles`` metadata, as rosbag2 (Jazzy) writes it.
* ``RosMcapWriter``: schemas, channels, messages as raw CDR bytes; in chunks of at most
  ``CHUNK_BYTES`` flushed on a period, so that a killed writer loses at most the chunk in
  progress and damage loses only the chunks it hits. Every schema and channel is written
  twice: in its chunk and once more outside any chunk, so that losing the chunk that
  defined a channel does not orphan the channel's later messages.
* ``keep``: a metadata record written again after the first chunk, every
  ``REPEAT_BYTES`` of file after that, and at the end: what a reader cannot do without
  (the run configuration) is in more than one place, so no single damaged chunk or record
  loses it.
* ``bag_metadata``: the ``rosbag2`` metadata record a closed file ends with, as rosbag2's
  MCAP storage writes it (``ros2 bag info`` reads the distro, topics and counts from it).

Reading is ``mcap_read``'s; ``mcap_io`` is the face of both (and repairs).
"""

from __future__ import annotations

import functools
import os
import sys
import time
from pathlib import Path
from typing import IO, Any

__all__ = ["message_definition", "type_hash", "qos_yaml", "RosMcapWriter", "CHUNK_BYTES",
           "REPEAT_BYTES", "bag_metadata", "ROS_DISTRO", "INFINITE_NS", "BAG_METADATA_VERSION"]

#: the ROS distribution the stack's wheels are (rosbag2's ``ros_distro``)
ROS_DISTRO = "jazzy"
#: rosbag2's metadata format version of that distribution
BAG_METADATA_VERSION = 9

#: chunk size limit [bytes of uncompressed records] of the recorder and the batch
#: simulator's recordings: what one damaged chunk loses at most (scripts/bench_record.py
#: --chunks measures the trade-off against file size and write cost)
CHUNK_BYTES = 64 * 1024

#: [bytes of file] how far apart the copies of a kept metadata record are written at most
REPEAT_BYTES = 1 << 20

_SEPARATOR = "=" * 80


def _share_dirs() -> list[Path]:
    dirs = [Path(p) / "share" for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep)
            if p]
    dirs.append(Path(sys.prefix) / "share")
    return dirs


def _msg_text(pkg: str, name: str) -> str:
    for share in _share_dirs():
        f = share / pkg / "msg" / f"{name}.msg"
        if f.is_file():
            return f.read_text()
    raise FileNotFoundError(f"no definition of {pkg}/msg/{name} under "
                            f"{', '.join(map(str, _share_dirs()))}")


@functools.cache
def _parsed(pkg: str, name: str) -> tuple[str, Any, tuple[tuple[str, str], ...]]:
    """(.msg text, rosbags' parse of it, (package, name) of every message type its fields
    use, in field order) of the installed ``pkg/msg/name``."""
    from rosbags.typesys import get_types_from_msg
    from rosbags.typesys.base import Nodetype

    text = _msg_text(pkg, name)
    types = get_types_from_msg(text, f"{pkg}/msg/{name}")
    used = []
    for _, desc in types[f"{pkg}/msg/{name}"][1]:
        if desc[0] in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            desc = desc[1][0]  # (element description, bound)
        if desc[0] == Nodetype.NAME:
            parts = desc[1].split("/")  # rosbags resolves Header and names in the package
            used.append((parts[0], parts[-1]))
    return text, types, tuple(used)


def _dependencies(pkg: str, name: str) -> list[tuple[str, str]]:
    """Every message type ``pkg/msg/name`` uses, directly or not, depth first in field
    order (the order rosbag2 concatenates their definitions in)."""
    seen: list[tuple[str, str]] = []
    stack = list(reversed(_parsed(pkg, name)[2]))
    while stack:
        dep = stack.pop()
        if dep in seen:
            continue
        seen.append(dep)
        stack.extend(reversed(_parsed(*dep)[2]))
    return seen


def message_definition(type_name: str) -> str:
    """Full ros2msg definition of ``pkg/msg/Name`` (or ``pkg/Name``) with dependencies.

    The installed ``.msg`` files' own text, comments included, concatenated as rosbag2
    does; rosbags' parser finds the dependencies. rosbags' own ``generate_msgdef`` is not
    used: it writes a normalised text without the comments (e.g. 197 bytes for
    geometry_msgs/msg/Twist where rosbag2 writes 475), not the bytes rosbag2 records.
    tests/recordings/test_mcap_io.py checks the bytes of every recorded type.
    """
    parts = type_name.split("/")
    pkg, name = parts[0], parts[-1]
    chunks = [_parsed(pkg, name)[0].rstrip("\n")]
    for dpkg, dname in _dependencies(pkg, name):
        chunks.append(f"{_SEPARATOR}\nMSG: {dpkg}/{dname}\n{_msg_text(dpkg, dname).rstrip()}")
    return "\n".join(chunks) + "\n"


def type_hash(type_name: str) -> str:
    """The RIHS01 type hash of ``pkg/msg/Name`` (or ``pkg/Name``), from the installed
    ``.msg`` files as rosbags parses them: what rclpy reports as a writer's
    ``topic_type_hash`` and rosbag2 records for the channel.

    Equal to rclpy's for 151 of the 156 message types installed with this project's ROS
    packages, every recorded type included (tests/recordings/test_mcap_io.py checks them).
    The 5 others have ``char`` fields, which rosbags' .msg parser reads as uint8. rosbags'
    own ROS2_JAZZY type store is not used: it takes 0.7 s to load and hashes 6 of the
    installed types differently (newer versions than its copy).
    """
    from rosbags.typesys import Stores, get_typestore

    parts = type_name.split("/")
    pkg, name = parts[0], parts[-1]
    store = get_typestore(Stores.EMPTY)
    for dep in [(pkg, name), *_dependencies(pkg, name)]:
        store.register(_parsed(*dep)[1])
    return store.hash_rihs01(f"{pkg}/msg/{name}")


#: rmw's RMW_DURATION_INFINITE [ns] (rmw/time.h: {9223372036 s, 854775807 ns}): what Fast DDS
#: reports in the graph for a deadline, lifespan or lease a publisher leaves unspecified,
#: and so what rosbag2 records for it
INFINITE_NS = 2**63 - 1


def qos_yaml(reliability: str = "reliable", durability: str = "volatile",
             history: str = "keep_last", depth: int = 10, deadline: int = INFINITE_NS,
             lifespan: int = INFINITE_NS, liveliness: str = "automatic",
             lease: int = INFINITE_NS, avoid_ros_namespace_conventions: bool = False) -> str:
    """``offered_qos_profiles`` channel metadata (one publisher), as rosbag2 Jazzy writes it
    (``serialize_rclcpp_qos_vector``, version 9: policies by name, times as rmw_time_t's
    sec and nsec); durations in ns."""
    def t(ns: int) -> str:
        return f"\n    sec: {int(ns) // 10**9}\n    nsec: {int(ns) % 10**9}"

    avoid = str(bool(avoid_ros_namespace_conventions)).lower()
    return (f"- history: {history}\n  depth: {int(depth)}\n  reliability: {reliability}\n"
            f"  durability: {durability}\n  deadline:{t(deadline)}\n  lifespan:{t(lifespan)}\n"
            f"  liveliness: {liveliness}\n  liveliness_lease_duration:{t(lease)}\n"
            f"  avoid_ros_namespace_conventions: {avoid}")


class RosMcapWriter:
    """Writes a ROS 2 MCAP file: CDR bytes as received, one channel per topic.

    flush_period : seconds between forced chunk flushes (crash safety); 0 disables.
    """

    def __init__(self, path: str | Path, flush_period: float = 0.5,
                 chunk_size: int = CHUNK_BYTES, compression: str = "zstd"):
        from mcap.writer import CompressionType, Writer

        self.path = Path(path)
        self._fh: IO[bytes] = self.path.open("wb")
        comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                "none": CompressionType.NONE}[compression]
        self._w = Writer(self._fh, chunk_size=chunk_size, compression=comp)
        self._w.start(profile="ros2", library="formation-ilc")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._period = flush_period
        self._last_flush = time.monotonic()
        self._copies: list[Any] = []  # schema and channel records still to write outside chunks
        #: per topic: type, offered QoS, type hash, messages written (the rosbag2 record)
        self._topics: dict[str, list[Any]] = {}
        self._span: list[int] = []  # first and last log time [ns]
        self.count = 0
        self.closed = False
        #: metadata records written again as the file grows (``keep``), and where the last
        #: copies end (None: none since they were kept)
        self._kept: dict[str, dict[str, str]] = {}
        self._kept_at: int | None = None
        self.repeat_bytes = REPEAT_BYTES

    def keep(self, name: str, data: dict[str, str]) -> None:
        """Write metadata record ``name`` now and again: after the chunk in progress, then
        every ``repeat_bytes`` of file, and before the summary at the end."""
        self._kept[name] = {k: str(v) for k, v in data.items()}
        self.metadata(name, self._kept[name])
        self._kept_at = None

    def channel(self, topic: str, type_name: str, qos: str, type_hash: str = "",
                extra: dict[str, str] | None = None) -> int:
        """Register (once) and return the channel id of ``topic``; ``extra``: metadata of
        the channel beside its QoS and type hash (written with the channel in its chunk,
        outside it, and in the summary)."""
        if topic in self._channels:
            return self._channels[topic]
        from mcap.records import Channel, Schema

        if type_name not in self._schemas:
            text = message_definition(type_name).encode()
            sid = self._w.register_schema(name=type_name, encoding="ros2msg", data=text)
            self._schemas[type_name] = sid
            self._copies.append(Schema(id=sid, name=type_name, encoding="ros2msg", data=text))
        meta = {"offered_qos_profiles": qos}
        if type_hash:
            meta["topic_type_hash"] = type_hash
        meta.update(extra or {})
        sid = self._schemas[type_name]
        cid = self._w.register_channel(topic=topic, message_encoding="cdr", schema_id=sid,
                                       metadata=meta)
        self._channels[topic] = cid
        self._topics[topic] = [type_name, qos, type_hash, 0]
        self._copies.append(Channel(id=cid, topic=topic, message_encoding="cdr",
                                    schema_id=sid, metadata=meta))
        return cid

    def has_channel(self, topic: str) -> bool:
        return topic in self._channels

    def write(self, topic: str, data: bytes, log_time: int, publish_time: int,
              sequence: int = 0) -> None:
        try:
            self._w.add_message(self._channels[topic], log_time=int(log_time),
                                data=bytes(data), publish_time=int(publish_time),
                                sequence=sequence)
        except OSError as exc:
            raise self._named(exc) from exc
        self.count += 1
        self._topics[topic][3] += 1
        t = int(log_time)
        if not self._span:
            self._span = [t, t]
        elif t < self._span[0]:
            self._span[0] = t
        elif t > self._span[1]:
            self._span[1] = t
        if self._period > 0 and time.monotonic() - self._last_flush >= self._period:
            self.flush()

    def _named(self, exc: OSError) -> OSError:
        """``exc`` naming this file (a full disk's message names what could not be
        written)."""
        return OSError(exc.errno, exc.strerror, str(self.path))

    def metadata(self, name: str, data: dict[str, str]) -> None:
        self._w.add_metadata(name, {k: str(v) for k, v in data.items()})

    def flush(self) -> None:
        """Close the chunk in progress and push it to the file, followed by a copy (outside
        any chunk) of the schemas and channels registered since the last flush."""
        from mcap.data_stream import RecordBuilder

        try:
            self._w.flush()
            if self._copies:
                b = RecordBuilder()
                for rec in self._copies:
                    rec.write(b)
                self._fh.write(b.end())
                self._copies = []
            self._repeat()
            self._fh.flush()
        except OSError as exc:
            raise self._named(exc) from exc
        self._last_flush = time.monotonic()

    def _repeat(self, now: bool = False) -> None:
        """The kept metadata records again, when the file has grown by ``repeat_bytes``
        since their last copies (or had none since they were kept), or ``now``."""
        if not self._kept:
            return
        pos = self._fh.tell()
        if now or self._kept_at is None or pos - self._kept_at >= self.repeat_bytes:
            for name, data in self._kept.items():
                self._w.add_metadata(name, data)
            self._kept_at = self._fh.tell()

    def close(self) -> None:
        if not self.closed:
            self.flush()
            self._repeat(now=True)
            self._w.add_metadata("rosbag2", {"serialized_metadata": bag_metadata(
                self.path.name, self._topics, self._span)})
            self._w.finish()
            self._fh.close()
            self.closed = True

    def __enter__(self) -> RosMcapWriter:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def bag_metadata(name: str, topics: dict[str, list[Any]], span: list[int]) -> str:
    """rosbag2's metadata of one MCAP file (YAML, the ``serialized_metadata`` of the
    ``rosbag2`` record): ``topics`` maps a topic to [type, offered QoS YAML, type hash,
    messages]; ``span`` is the first and last log time [ns] (empty: no message).

    In the shape rosbag2 Jazzy's ``convert<BagMetadata>`` decodes at version 9: each
    topic's ``offered_qos_profiles`` a sequence of QoS maps (the channel's metadata
    keeps the same profiles as one YAML string, as rosbag2's MCAP storage writes it);
    tests/recordings/rosbag2_jazzy.py decodes it with rosbag2's rules."""
    import yaml

    start, end = (span[0], span[1]) if span else (0, 0)
    count = sum(t[3] for t in topics.values())
    doc = {
        "version": BAG_METADATA_VERSION, "storage_identifier": "mcap",
        "duration": {"nanoseconds": end - start},
        "starting_time": {"nanoseconds_since_epoch": start},
        "message_count": count,
        "topics_with_message_count": [
            {"topic_metadata": {"name": topic, "type": ty, "serialization_format": "cdr",
                                "offered_qos_profiles": yaml.safe_load(qos),
                                "type_description_hash": h},
             "message_count": n}
            for topic, (ty, qos, h, n) in sorted(topics.items())],
        "compression_format": "", "compression_mode": "",
        "relative_file_paths": [name],
        "files": [{"path": name, "starting_time": {"nanoseconds_since_epoch": start},
                   "duration": {"nanoseconds": end - start}, "message_count": count}],
        "custom_data": {}, "ros_distro": ROS_DISTRO,
    }
    return str(yaml.safe_dump(doc, sort_keys=False))
