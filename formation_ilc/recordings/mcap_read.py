"""Reading MCAP files, also cut short by a crash or damaged in the middle.

* ``read_messages``: every message that reads back: a record that does not parse, or a
  chunk whose CRC does not match, is skipped and reading resumes at the next valid record
  (``ReadReport`` says what was lost: byte ranges, chunks, messages, their log times).
* ``records``: every record that reads back, in file order (what ``repair`` copies).
* ``read_metadata``: the metadata records by name.

Writing is ``mcap_write``'s; ``mcap_io`` is the face of both (and repairs).
"""

from __future__ import annotations

import mmap
import os
import re
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import Any

__all__ = ["RawMessage", "read_messages", "read_metadata", "records", "ReadReport",
           "Damage", "FileInfo", "MAX_CHUNK_BYTES"]

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


def records(path: Path, report: ReadReport | None = None) -> Iterator[Any]:
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
    for rec in records(Path(path), ReadReport()):
        if isinstance(rec, Schema):
            schemas[rec.id] = rec.name
    for rec in records(Path(path), ReadReport()):
        if isinstance(rec, Channel):
            channels[rec.id] = (rec.topic, schemas.get(rec.schema_id, ""))
            if info is not None and rec.metadata:
                info.channels.setdefault(rec.topic, {}).update(dict(rec.metadata))
        elif isinstance(rec, Metadata) and info is not None:
            info.metadata.append((rec.name, dict(rec.metadata)))
    for rec in records(Path(path), rep):
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

    return {rec.name: dict(rec.metadata) for rec in records(Path(path))
            if isinstance(rec, Metadata)}
