"""MCAP files as ROS 2 tools write them (profile ``ros2``), without importing rclpy.

* ``message_definition``: the full ``ros2msg`` text of a type with its dependencies, read
  from the installed ``.msg`` files, concatenated as rosbag2 does; ``type_hash``: its RIHS01
  hash (both with rosbags' .msg parser).
* ``qos_yaml``: a channel's ``offered_qos_profiles`` metadata, as rosbag2 (Jazzy) writes it.
* ``RosMcapWriter``: schemas, channels, messages as raw CDR bytes; in chunks of at most
  ``CHUNK_BYTES`` flushed on a period, so that a killed writer loses at most the chunk in
  progress and damage loses only the chunks it hits. Every schema and channel is written
  twice: in its chunk and once more outside any chunk, so that losing the chunk that
  defined a channel does not orphan the channel's later messages.
* ``read_messages``: every message that reads back, also from a file cut short by a crash
  or damaged in the middle: a record that does not parse, or a chunk whose CRC does not
  match, is skipped and reading resumes at the next valid record (``ReadReport`` says what
  was lost: byte ranges, chunks, messages, their log times).
* ``repair``: rewrite a cut-short or damaged file with a complete summary and footer, and
  put back what it can rebuild (a lost message of the run configuration, from a copy).
* ``keep``: a metadata record written again after the first chunk, every
  ``REPEAT_BYTES`` of file after that, and at the end: what a reader cannot do without
  (the run configuration) is in more than one place, so no single damaged chunk or record
  loses it.
* ``bag_metadata``: the ``rosbag2`` metadata record a closed file ends with, as rosbag2's
  MCAP storage writes it (``ros2 bag info`` reads the distro, topics and counts from it).
"""

from __future__ import annotations

import functools
import mmap
import os
import re
import struct
import sys
import time
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import IO, Any

__all__ = ["message_definition", "type_hash", "qos_yaml", "RosMcapWriter", "RawMessage",
           "read_messages", "repair", "read_metadata", "ReadReport", "Damage", "CHUNK_BYTES",
           "FileInfo", "REPEAT_BYTES", "RepairError", "Repairing", "repair_with",
           "bag_metadata", "ROS_DISTRO", "INFINITE_NS"]

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


@dataclass(frozen=True)
class RawMessage:
    topic: str
    schema: str
    log_time: int
    publish_time: int
    data: bytes


_MAGIC = b"\x89MCAP0\r\n"
#: record opcodes of the MCAP format (0x01 header ... 0x0F data end)
_OPCODES = range(0x01, 0x10)
_CHUNK, _MESSAGE_INDEX, _FOOTER = 0x06, 0x07, 0x02
#: the most bytes one chunk may hold uncompressed for this reader: what it holds in memory
#: at once (a chunk is read whole). The mcap writers' chunks are 64 KiB to a few MiB; a
#: larger claim is read only as far as its data really inflates, and refused past this
MAX_CHUNK_BYTES = 256 << 20
#: [bytes] decompression proceeds in pieces of this size: memory follows the real output
_PIECE = 1 << 20


class _Bad(Exception):
    """A record that does not parse (or fails its CRC) at this offset."""


@dataclass
class Damage:
    """Unreadable bytes [start, end) of a file, and what they held where that is known:
    ``chunks`` and ``messages`` lost (from the file's chunk index, or from the message
    indexes that follow a lost chunk), with their log times [ns]."""

    start: int
    end: int
    reason: str
    chunks: int = 0
    messages: int = 0
    log_start: int | None = None
    log_end: int | None = None

    def covers(self, t0: int, t1: int) -> None:
        self.log_start = t0 if self.log_start is None else min(self.log_start, t0)
        self.log_end = t1 if self.log_end is None else max(self.log_end, t1)


@dataclass
class ReadReport:
    """What reading a file found: its size, the messages that read back, the damage it
    skipped (``damage``), whether it ends cut short (no footer: a writer that crashed or
    was killed; the bytes after the last complete record, ``tail_bytes``, are lost), and
    messages whose channel definition was lost with a damaged chunk (``orphans``)."""

    size: int = 0
    messages: int = 0
    chunks: int = 0
    damage: list[Damage] = field(default_factory=list)
    cut_short: bool = False
    tail_bytes: int = 0
    orphans: int = 0
    #: from the file's own statistics record, when its summary reads back
    total_messages: int | None = None
    total_chunks: int | None = None
    #: log time [ns] of the earliest message read back (what lost log times are told from)
    first_log_time: int | None = None

    @property
    def damaged(self) -> bool:
        return bool(self.damage) or self.orphans > 0

    @property
    def lost_messages(self) -> int:
        """Messages known lost: the file's own count minus those read back when the
        summary survived, else what the surviving message indexes list."""
        if self.total_messages is not None:
            return max(0, self.total_messages - self.messages)
        return sum(d.messages for d in self.damage) + self.orphans

    def lines(self) -> list[str]:
        """One line per finding, for a user (empty for an intact file)."""
        out = []
        for d in self.damage:
            what = []
            if d.chunks:
                what.append(f"{d.chunks} chunk{'s' * (d.chunks != 1)}")
            if d.messages:
                what.append(f"{d.messages} messages")
            if d.log_start is not None and d.log_end is not None:
                t0 = self.first_log_time if self.first_log_time is not None else 0
                what.append(f"log times {(d.log_start - t0) / 1e9:.3f} to "
                            f"{(d.log_end - t0) / 1e9:.3f} s after the first message")
            out.append(f"bytes {d.start}-{d.end} ({d.end - d.start} bytes) unreadable: "
                       f"{d.reason}; lost {', '.join(what) or 'an unknown part'}")
        if self.orphans:
            out.append(f"{self.orphans} messages of channels whose definition was lost")
        if self.cut_short:
            out.append("the file ends cut short (no footer: the writer stopped before "
                       "closing it)" + (f"; the last {self.tail_bytes} bytes are an "
                                        f"incomplete record" if self.tail_bytes else ""))
        return out


def _stream(content: bytes | bytearray | memoryview) -> Any:
    from mcap.data_stream import ReadDataStream

    return ReadDataStream(BytesIO(content))


def _inflate(compression: str, data: bytes | memoryview, size: int) -> bytes | bytearray:
    """A chunk's records, decompressed in pieces up to one byte past its claimed ``size``:
    memory follows what the data really inflates to, never the claim (a damaged size field
    of terabytes allocates nothing), and never more than MAX_CHUNK_BYTES. _Bad when the
    chunk cannot be read (the caller compares the length with ``size``)."""
    if size > MAX_CHUNK_BYTES:
        raise _Bad(f"a chunk of {size} bytes uncompressed, more than this reader holds in "
                   f"memory ({MAX_CHUNK_BYTES})")
    if compression == "":
        return bytes(data)
    if compression == "zstd":
        import zstandard

        if zstandard.frame_content_size(bytes(data[:18])) not in (-1, size):
            raise _Bad("zstd frame size mismatch")
        out = bytearray()
        with zstandard.ZstdDecompressor().stream_reader(bytes(data)) as rd:
            while len(out) <= size:
                piece = rd.read(min(_PIECE, size + 1 - len(out)))
                if not piece:
                    break
                out += piece
        return out
    if compression == "lz4":
        import lz4.frame  # type: ignore[import-not-found,unused-ignore]

        lz: bytes = lz4.frame.LZ4FrameDecompressor().decompress(bytes(data),
                                                              max_length=size + 1)
        return lz
    raise _Bad(f"unknown compression {compression[:20]!r}")


def _chunk_records(content: bytes | memoryview) -> list[Any]:
    """The records inside a chunk record's content; _Bad if it does not decompress, fails
    its CRC or does not parse."""
    from mcap.records import Channel, Chunk, Message, Schema

    st = _stream(content)
    ch = Chunk.read(st)
    if st.count != len(content):
        raise _Bad("chunk length mismatch")
    data = _inflate(ch.compression, ch.data, ch.uncompressed_size)
    if len(data) != ch.uncompressed_size:
        raise _Bad("uncompressed size mismatch")
    if ch.uncompressed_crc != 0 and zlib.crc32(data) != ch.uncompressed_crc:
        raise _Bad("chunk CRC mismatch")
    out: list[Any] = []
    pos, n = 0, len(data)
    while pos < n:
        if pos + 9 > n:
            raise _Bad("record cut inside a chunk")
        op, length = data[pos], struct.unpack_from("<Q", data, pos + 1)[0]
        body = data[pos + 9: pos + 9 + length]
        if len(body) != length:
            raise _Bad("record longer than its chunk")
        if op == 0x04:
            out.append(Channel.read(_stream(body)))
        elif op == 0x05:
            out.append(Message.read(_stream(body), length))
        elif op == 0x03:
            out.append(Schema.read(_stream(body)))
        pos += 9 + length
    return out


def _record(op: int, content: bytes | memoryview, exact: bool) -> list[Any]:
    """The record(s) of one top-level record (a chunk gives its inner records); _Bad if it
    does not parse, or (``exact``: when resynchronising after damage) does not fill its
    length exactly."""
    from mcap import records as r

    if op == _CHUNK:
        return [_ChunkMark(len(content)), *_chunk_records(content)]
    readers = {0x01: r.Header.read, 0x02: r.Footer.read, 0x03: r.Schema.read,
               0x04: r.Channel.read, 0x07: r.MessageIndex.read, 0x08: r.ChunkIndex.read,
               0x09: r.Attachment.read, 0x0A: r.AttachmentIndex.read,
               0x0B: r.Statistics.read, 0x0C: r.Metadata.read, 0x0D: r.MetadataIndex.read,
               0x0E: r.SummaryOffset.read, 0x0F: r.DataEnd.read}
    st = _stream(content)
    if op == 0x05:
        return [r.Message.read(st, len(content))]
    rec = readers[op](st)
    if exact and st.count != len(content):
        raise _Bad("record length mismatch")
    return [rec]


@dataclass(frozen=True)
class _ChunkMark:
    """Marks the start of a chunk's records in the record stream."""

    length: int


def _parse_at(buf: Any, pos: int, exact: bool) -> tuple[int, list[Any]]:
    """(end offset, records) of the record at ``pos``; _Bad if there is none."""
    n = len(buf)
    if pos + 9 > n:
        raise _Bad("cut")
    op = buf[pos]
    if op not in _OPCODES:
        raise _Bad(f"unknown opcode {op:#x}")
    length = struct.unpack_from("<Q", buf, pos + 1)[0]
    end = pos + 9 + length
    if end > n:
        raise _Bad("cut")
    try:
        recs = _record(op, memoryview(buf)[pos + 9: end], exact)
    except _Bad:
        raise
    except Exception as exc:  # noqa: BLE001 - anything a damaged record makes a parser do
        raise _Bad(f"{type(exc).__name__}: {exc}"[:120]) from None
    return end, recs


#: opcodes a reader may resynchronise on: every record but the header, a bare message and
#: an attachment (none of which this writer puts after the start)
_RESYNC = re.compile(rb"[\x02-\x04\x06-\x08\x0a-\x0f]")


def _resync(buf: Any, pos: int) -> int:
    """The offset of the next valid record after ``pos`` (len(buf) if none): a candidate
    must fit in the file and parse exactly, a chunk must pass its CRC."""
    n = len(buf)
    for m in _RESYNC.finditer(buf, pos + 1, max(pos + 1, n - 9)):
        q = m.start()
        length = struct.unpack_from("<Q", buf, q + 1)[0]
        if q + 9 + length > n or (buf[q] == _FOOTER and q + 9 + length + 8 != n):
            continue
        try:
            _parse_at(buf, q, exact=True)
            return q
        except _Bad:
            pass
    return n


def _summary(buf: Any) -> list[Any]:
    """The summary section's records when the file ends with an intact footer (empty
    otherwise): its schemas and channels, statistics and chunk index."""
    n = len(buf)
    if n < 8 + 29 + 8 or bytes(buf[n - 8:]) != _MAGIC:
        return []
    try:
        end, (footer,) = _parse_at(buf, n - 8 - 29, exact=True)
        start = footer.summary_start
        if start == 0 or not 8 <= start < n - 37:
            return []
        out: list[Any] = []
        pos = start
        while pos < n - 37:
            pos, recs = _parse_at(buf, pos, exact=False)
            out += recs
        return out
    except (_Bad, ValueError):
        return []


def _records(path: Path, report: ReadReport | None = None) -> Iterator[Any]:
    """Every record that reads back, in file order (a chunk's inner records in place of the
    chunk, after a ``_ChunkMark``), skipping damage; ``report`` gets what was lost."""
    from mcap.records import ChunkIndex, MessageIndex, Statistics

    rep = report if report is not None else ReadReport()
    with path.open("rb") as fh:
        rep.size = os.fstat(fh.fileno()).st_size
        if rep.size == 0:
            rep.cut_short = True
            return
        buf = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
        try:
            yield from _walk(buf, rep, _summary(buf), ChunkIndex, MessageIndex, Statistics)
        finally:
            buf.close()


def _walk(buf: Any, rep: ReadReport, summary: list[Any], ChunkIndex: Any,
          MessageIndex: Any, Statistics: Any) -> Iterator[Any]:
    n = len(buf)
    chunk_starts: list[int] = []
    for rec in summary:  # definitions first: they may be all that is left of a channel's
        if isinstance(rec, Statistics):
            rep.total_messages, rep.total_chunks = rec.message_count, rec.chunk_count
        elif not isinstance(rec, ChunkIndex):
            yield rec
    index = {c.chunk_start_offset: c for c in summary if isinstance(c, ChunkIndex)}
    pos = 8
    if bytes(buf[:8]) != _MAGIC:
        pos = 0
    damage: Damage | None = None
    footer = False
    while pos < n:
        try:
            end, recs = _parse_at(buf, pos, exact=False)
        except _Bad as exc:
            q = _resync(buf, pos)
            if q == n and str(exc) == "cut":
                rep.cut_short = True
                rep.tail_bytes = n - pos
                break
            damage = Damage(pos, q, str(exc))
            rep.damage.append(damage)
            pos = q
            continue
        if recs and isinstance(recs[0], _ChunkMark):
            rep.chunks += 1
            chunk_starts.append(pos)
            damage = None
        elif damage is not None and isinstance(recs[0], MessageIndex) and recs[0].records:
            # the index of a chunk lost to the damage before it: what that chunk held
            times = [t for t, _ in recs[0].records]
            damage.messages += len(times)
            damage.covers(min(times), max(times))
            damage.chunks = max(damage.chunks, 1)
        for rec in recs:
            if isinstance(rec, _ChunkMark):
                continue
            if isinstance(rec, Statistics) and rep.total_messages is None:
                rep.total_messages, rep.total_chunks = rec.message_count, rec.chunk_count
            yield rec
        pos = end
        if recs and type(recs[0]).__name__ == "Footer":
            footer = True
            break
    rep.cut_short = rep.cut_short or not footer
    if index:  # the file's own chunk index names the chunks the damage took exactly
        read = set(chunk_starts)
        for d in rep.damage:
            lost = [c for off, c in index.items() if d.start <= off < d.end and off not in read]
            if lost:
                d.chunks = len(lost)
                for c in lost:
                    d.covers(c.message_start_time, c.message_end_time)


@dataclass
class FileInfo:
    """What a file says besides its messages, as far as it reads back: every metadata
    record (name, data) in file order, and every channel's metadata by topic."""

    metadata: list[tuple[str, dict[str, str]]] = field(default_factory=list)
    channels: dict[str, dict[str, str]] = field(default_factory=dict)


def read_messages(path: str | Path, topics: set[str] | None = None,
                  report: ReadReport | None = None,
                  info: FileInfo | None = None) -> Iterator[RawMessage]:
    """Messages in file order, as raw CDR bytes. Works on files without a summary, and on
    damaged files (what reads back; ``report`` says what did not). ``info`` gets the
    metadata records and channel metadata before the first message is given."""
    from mcap.records import Channel, Message, Metadata, Schema

    rep = report if report is not None else ReadReport()
    schemas: dict[int, str] = {}
    channels: dict[int, tuple[str, str]] = {}
    # every readable schema and channel first: a channel whose chunk is damaged has its
    # copy outside the chunks, which may come after messages of later, intact chunks
    for rec in _records(Path(path), ReadReport()):
        if isinstance(rec, Schema):
            schemas[rec.id] = rec.name
    for rec in _records(Path(path), ReadReport()):
        if isinstance(rec, Channel):
            channels[rec.id] = (rec.topic, schemas.get(rec.schema_id, ""))
            if info is not None and rec.metadata:
                info.channels.setdefault(rec.topic, {}).update(dict(rec.metadata))
        elif isinstance(rec, Metadata) and info is not None:
            info.metadata.append((rec.name, dict(rec.metadata)))
    for rec in _records(Path(path), rep):
        if isinstance(rec, Schema):
            schemas[rec.id] = rec.name
        elif isinstance(rec, Channel):
            channels[rec.id] = (rec.topic, schemas.get(rec.schema_id, ""))
        elif isinstance(rec, Message):
            if rec.channel_id not in channels:
                rep.orphans += 1
                continue
            rep.messages += 1
            if rep.first_log_time is None or rec.log_time < rep.first_log_time:
                rep.first_log_time = rec.log_time
            topic, schema = channels[rec.channel_id]
            if topics is None or topic in topics:
                yield RawMessage(topic, schema, rec.log_time, rec.publish_time, rec.data)


def read_metadata(path: str | Path) -> dict[str, dict[str, str]]:
    from mcap.records import Metadata

    return {rec.name: dict(rec.metadata) for rec in _records(Path(path))
            if isinstance(rec, Metadata)}


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
    n = records = 0
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
            for rec in _records(src, rep):
                records += 1
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
            if not records:
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
