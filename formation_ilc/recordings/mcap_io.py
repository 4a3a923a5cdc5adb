"""MCAP files as ROS 2 tools write them (profile ``ros2``), without importing rclpy.

The face of ``mcap_write`` (writing: ``message_definition``, ``type_hash``, ``qos_yaml``,
``RosMcapWriter`` with its ``keep``, ``bag_metadata``; their docstrings say what each does) and
``mcap_read`` (reading: ``read_messages`` and its ``ReadReport``, ``records``,
``read_metadata``), and repair, which does both:

* ``repair``: rewrite a cut-short or damaged file with a complete summary and footer, and
  put back what it can rebuild (a lost message of the run configuration, from a copy).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from formation_ilc.recordings.mcap_read import (
    Damage,
    FileInfo,
    RawMessage,
    ReadReport,
    read_messages,
    read_metadata,
    records,
)
from formation_ilc.recordings.mcap_write import (
    CHUNK_BYTES,
    INFINITE_NS,
    REPEAT_BYTES,
    ROS_DISTRO,
    RosMcapWriter,
    bag_metadata,
    message_definition,
    qos_yaml,
    type_hash,
)

__all__ = ["message_definition", "type_hash", "qos_yaml", "RosMcapWriter", "RawMessage",
           "read_messages", "repair", "read_metadata", "ReadReport", "Damage", "CHUNK_BYTES",
           "FileInfo", "REPEAT_BYTES", "RepairError", "Repairing", "repair_with",
           "bag_metadata", "ROS_DISTRO", "INFINITE_NS"]


class RepairError(ValueError):
    """A file ``repair`` cannot make a recording of (nothing reads back)."""


@dataclass
class Repairing:
    """What ``repair`` copied, for a ``rebuild`` hook that puts back what was lost: the new
    file's writer, the metadata records and channel metadata that read back
    (``info``), the topics that kept a message, the earliest log time, and the new file's
    channel and schema ids by topic and type name."""

    writer: Any
    info: FileInfo
    topics: set[str]
    first_log_time: int | None
    channels: dict[str, int]
    schemas: dict[str, int]

    def channel(self, topic: str, type_name: str, metadata: dict[str, str]) -> int:
        """The new file's channel of ``topic`` (registered, with ``metadata``, if none)."""
        if topic in self.channels:
            return self.channels[topic]
        if type_name not in self.schemas:
            self.schemas[type_name] = self.writer.register_schema(
                type_name, "ros2msg", message_definition(type_name).encode())
        self.channels[topic] = self.writer.register_channel(topic, "cdr",
                                                            self.schemas[type_name], metadata)
        return self.channels[topic]


def repair(src: str | Path, dst: str | Path, report: ReadReport | None = None) -> int:
    """``repair_with`` without a rebuild: the number of messages kept."""
    return repair_with(src, dst, report)[0]


def repair_with(src: str | Path, dst: str | Path, report: ReadReport | None = None,
                rebuild: Callable[[Repairing], list[str]] | None = None,
                peek: Callable[[str, bytes], None] | None = None
                ) -> tuple[int, list[str]]:
    """Copy everything that reads back from ``src`` into a complete file ``dst``
    (``report`` gets what did not); ``rebuild`` then puts back what it can (its notes are
    returned). ``peek(topic, data)`` sees every message copied, before ``rebuild``.

    Returns (messages kept, notes). ``src`` is not changed. The copy is written beside
    ``dst`` and moved into place once complete; RepairError, with nothing written, when no
    record of ``src`` reads back (not an MCAP file, or nothing of it left).
    """
    from mcap.records import Channel, Message, Metadata, Schema
    from mcap.writer import Writer

    src, dst = Path(src), Path(dst)
    if src.resolve() == dst.resolve():
        raise ValueError("repair writes a new file: give a different output path")
    rep = report if report is not None else ReadReport()
    n = seen = 0
    tmp = dst.with_name(f".{dst.name}.repairing")
    notes: list[str] = []
    try:
        with tmp.open("wb") as fh:
            w = Writer(fh)
            w.start(profile="ros2", library="formation-ilc repair")
            sid: dict[int, int] = {}
            cid: dict[int, int] = {}
            names: dict[int, str] = {}
            state = Repairing(w, FileInfo(), set(), None, {}, {})
            for rec in records(src, rep):
                seen += 1
                if isinstance(rec, Schema) and rec.id not in sid:
                    sid[rec.id] = w.register_schema(rec.name, rec.encoding, rec.data)
                    state.schemas.setdefault(rec.name, sid[rec.id])
                elif isinstance(rec, Channel) and rec.id not in cid:
                    cid[rec.id] = w.register_channel(rec.topic, rec.message_encoding,
                                                     sid.get(rec.schema_id, 0),
                                                     dict(rec.metadata))
                    names[rec.id] = rec.topic
                    state.channels.setdefault(rec.topic, cid[rec.id])
                    if rec.metadata:
                        state.info.channels.setdefault(rec.topic, {}).update(
                            dict(rec.metadata))
                elif isinstance(rec, Message) and rec.channel_id in cid:
                    w.add_message(cid[rec.channel_id], rec.log_time, rec.data,
                                  rec.publish_time, rec.sequence)
                    state.topics.add(names[rec.channel_id])
                    if peek is not None:
                        peek(names[rec.channel_id], rec.data)
                    if state.first_log_time is None or rec.log_time < state.first_log_time:
                        state.first_log_time = rec.log_time
                    n += 1
                elif isinstance(rec, Metadata) and rec.name != "rosbag2":
                    # rosbag2's record describes the original file (its counts and span):
                    # left out of the copy rather than copied wrong
                    w.add_metadata(rec.name, dict(rec.metadata))
                    state.info.metadata.append((rec.name, dict(rec.metadata)))
            if not seen:
                raise RepairError("no MCAP record reads back (not an MCAP file, or nothing of "
                                  "it is left): nothing written")
            if rebuild is not None:
                notes = rebuild(state)
            w.finish()
        os.replace(tmp, dst)
    finally:
        if tmp.exists():
            tmp.unlink()
    return n, notes
