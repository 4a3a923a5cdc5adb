"""MCAP files as ROS 2 tools write them (profile ``ros2``), without importing rclpy.

* ``message_definition``: the full ``ros2msg`` text of a type with its dependencies, read
  from the installed ``.msg`` files, concatenated as rosbag2 does.
* ``qos_yaml``: a channel's ``offered_qos_profiles`` metadata, as rosbag2 (Jazzy) writes it.
* ``RosMcapWriter``: schemas, channels, messages as raw CDR bytes; chunked, and flushed on
  a period so that a killed writer loses at most the last period.
* ``read_messages``: every message that reads back, also from a file cut short by a crash.
* ``repair``: rewrite a cut-short file with a complete summary and footer.
"""

from __future__ import annotations

import os
import re
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

__all__ = ["message_definition", "qos_yaml", "RosMcapWriter", "RawMessage", "read_messages",
           "repair", "read_metadata"]

_PRIMITIVES = {"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16",
               "uint16", "int32", "uint32", "int64", "uint64", "string", "wstring"}
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


def _field_types(text: str, pkg: str) -> list[tuple[str, str]]:
    """(package, name) of every non-primitive field type of a .msg text."""
    out = []
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        typ = line.split()[0]  # constants (TYPE NAME=VALUE) are always primitive
        base = re.sub(r"(\[.*\])|(<=\d+)", "", typ)
        if base in _PRIMITIVES:
            continue
        if "/" in base:
            parts = base.split("/")
            out.append((parts[0], parts[-1]))
        elif base == "Header":
            out.append(("std_msgs", "Header"))
        else:
            out.append((pkg, base))
    return out


def message_definition(type_name: str) -> str:
    """Full ros2msg definition of ``pkg/msg/Name`` (or ``pkg/Name``) with dependencies."""
    parts = type_name.split("/")
    pkg, name = parts[0], parts[-1]
    main = _msg_text(pkg, name)
    seen: list[tuple[str, str]] = []
    stack = list(reversed(_field_types(main, pkg)))
    while stack:
        dep = stack.pop()
        if dep in seen:
            continue
        seen.append(dep)
        stack.extend(reversed(_field_types(_msg_text(*dep), dep[0])))
    chunks = [main.rstrip("\n")]
    for dpkg, dname in seen:
        chunks.append(f"{_SEPARATOR}\nMSG: {dpkg}/{dname}\n{_msg_text(dpkg, dname).rstrip()}")
    return "\n".join(chunks) + "\n"


_INFINITE = {"sec": 2147483647, "nsec": 4294967295}


def qos_yaml(reliability: str = "reliable", durability: str = "volatile",
             history: str = "keep_last", depth: int = 10) -> str:
    """``offered_qos_profiles`` channel metadata (one publisher), rosbag2 Jazzy style."""
    def t(v: dict[str, int]) -> str:
        return f"\n    sec: {v['sec']}\n    nsec: {v['nsec']}"

    return (f"- history: {history}\n  depth: {int(depth)}\n  reliability: {reliability}\n"
            f"  durability: {durability}\n  deadline:{t(_INFINITE)}\n  lifespan:{t(_INFINITE)}\n"
            f"  liveliness: automatic\n  liveliness_lease_duration:{t(_INFINITE)}\n"
            f"  avoid_ros_namespace_conventions: false")


class RosMcapWriter:
    """Writes a ROS 2 MCAP file: CDR bytes as received, one channel per topic.

    flush_period : seconds between forced chunk flushes (crash safety); 0 disables.
    """

    def __init__(self, path: str | Path, flush_period: float = 0.5,
                 chunk_size: int = 1 << 20, compression: str = "zstd"):
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
        self.count = 0
        self.closed = False

    def channel(self, topic: str, type_name: str, qos: str, type_hash: str = "") -> int:
        """Register (once) and return the channel id of ``topic``."""
        if topic in self._channels:
            return self._channels[topic]
        if type_name not in self._schemas:
            self._schemas[type_name] = self._w.register_schema(
                name=type_name, encoding="ros2msg",
                data=message_definition(type_name).encode())
        meta = {"offered_qos_profiles": qos}
        if type_hash:
            meta["topic_type_hash"] = type_hash
        cid = self._w.register_channel(topic=topic, message_encoding="cdr",
                                       schema_id=self._schemas[type_name], metadata=meta)
        self._channels[topic] = cid
        return cid

    def has_channel(self, topic: str) -> bool:
        return topic in self._channels

    def write(self, topic: str, data: bytes, log_time: int, publish_time: int,
              sequence: int = 0) -> None:
        self._w.add_message(self._channels[topic], log_time=int(log_time), data=bytes(data),
                            publish_time=int(publish_time), sequence=sequence)
        self.count += 1
        if self._period > 0 and time.monotonic() - self._last_flush >= self._period:
            self.flush()

    def metadata(self, name: str, data: dict[str, str]) -> None:
        self._w.add_metadata(name, {k: str(v) for k, v in data.items()})

    def flush(self) -> None:
        """Close the chunk in progress and push it to the file."""
        self._w.flush()
        self._fh.flush()
        self._last_flush = time.monotonic()

    def close(self) -> None:
        if not self.closed:
            self._w.finish()
            self._fh.close()
            self.closed = True

    def __enter__(self) -> RosMcapWriter:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


@dataclass(frozen=True)
class RawMessage:
    topic: str
    schema: str
    log_time: int
    publish_time: int
    data: bytes


def _records(path: Path) -> Iterator[Any]:
    """Every record that reads back, in file order; stops quietly where a file is cut."""
    from mcap.exceptions import McapError
    from mcap.stream_reader import StreamReader

    with path.open("rb") as fh:
        reader = StreamReader(fh, skip_magic=False, emit_chunks=False)
        try:
            yield from reader.records
        except (McapError, EOFError, ValueError, OSError, AssertionError, KeyError) as exc:
            if os.environ.get("FORMATION_ILC_DEBUG"):
                print(f"{path}: stopped reading at a cut: {exc!r}", file=sys.stderr)


def read_messages(path: str | Path, topics: set[str] | None = None) -> Iterator[RawMessage]:
    """Messages in file order, as raw CDR bytes. Works on files without a summary."""
    from mcap.records import Channel, Message, Schema

    schemas: dict[int, str] = {}
    channels: dict[int, tuple[str, str]] = {}
    for rec in _records(Path(path)):
        if isinstance(rec, Schema):
            schemas[rec.id] = rec.name
        elif isinstance(rec, Channel):
            channels[rec.id] = (rec.topic, schemas.get(rec.schema_id, ""))
        elif isinstance(rec, Message):
            topic, schema = channels.get(rec.channel_id, ("", ""))
            if topics is None or topic in topics:
                yield RawMessage(topic, schema, rec.log_time, rec.publish_time, rec.data)


def read_metadata(path: str | Path) -> dict[str, dict[str, str]]:
    from mcap.records import Metadata

    return {rec.name: dict(rec.metadata) for rec in _records(Path(path))
            if isinstance(rec, Metadata)}


def repair(src: str | Path, dst: str | Path) -> int:
    """Copy everything that reads back from ``src`` into a complete file ``dst``.

    Returns the number of messages kept. ``src`` is not changed.
    """
    from mcap.records import Channel, Message, Metadata, Schema
    from mcap.writer import Writer

    src, dst = Path(src), Path(dst)
    if src.resolve() == dst.resolve():
        raise ValueError("repair writes a new file: give a different output path")
    n = 0
    with dst.open("wb") as fh:
        w = Writer(fh)
        w.start(profile="ros2", library="formation-ilc repair")
        sid: dict[int, int] = {}
        cid: dict[int, int] = {}
        for rec in _records(src):
            if isinstance(rec, Schema) and rec.id not in sid:
                sid[rec.id] = w.register_schema(rec.name, rec.encoding, rec.data)
            elif isinstance(rec, Channel) and rec.id not in cid:
                cid[rec.id] = w.register_channel(rec.topic, rec.message_encoding,
                                                 sid.get(rec.schema_id, 0), dict(rec.metadata))
            elif isinstance(rec, Message) and rec.channel_id in cid:
                w.add_message(cid[rec.channel_id], rec.log_time, rec.data, rec.publish_time,
                              rec.sequence)
                n += 1
            elif isinstance(rec, Metadata):
                w.add_metadata(rec.name, dict(rec.metadata))
        w.finish()
    return n
