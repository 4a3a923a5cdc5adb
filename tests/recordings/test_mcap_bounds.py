"""The MCAP reader bounds its memory by what a chunk really inflates to, never by a ratio:
a sound file that the mcap library reads whole is never called damaged, and a chunk whose
size field lies (or that inflates beyond what the reader holds) costs no memory."""

from __future__ import annotations

import struct
import subprocess
import sys

import pytest

from formation_ilc.recordings.mcap_io import ReadReport, read_messages, repair


def _write(path, messages: int, size: int, chunk: int) -> None:
    from mcap.writer import CompressionType, Writer

    with path.open("wb") as fh:
        w = Writer(fh, chunk_size=chunk, compression=CompressionType.ZSTD)
        w.start(profile="", library="test")
        sid = w.register_schema("s", "jsonschema", b"{}")
        cid = w.register_channel("/zeros", "json", sid)
        for i in range(messages):
            w.add_message(cid, log_time=i, data=bytes(size), publish_time=i)
        w.finish()


def _mcap_library_count(path) -> int:
    from mcap.reader import make_reader

    with path.open("rb") as fh:
        return sum(1 for _ in make_reader(fh).iter_messages())


def test_a_valid_chunk_that_compresses_4000_to_1_reads_whole(tmp_path):
    """274 messages of 8 KiB of zeros in one chunk: 2.2 MB that zstd stores in a few
    hundred bytes. The ratio guard of before threw the chunk away and called the file
    damaged; the mcap library reads every message."""
    path = tmp_path / "zeros.mcap"
    _write(path, 274, 8192, chunk=4 << 20)
    assert _mcap_library_count(path) == 274
    rep = ReadReport()
    got = list(read_messages(path, report=rep))
    assert len(got) == 274 and all(m.data == bytes(8192) for m in got)
    assert not rep.damaged and not rep.cut_short and rep.chunks == 1
    assert repair(path, tmp_path / "copy.mcap") == 274


def _chunk_record(uncompressed_size: int, compression: str, data: bytes) -> bytes:
    """An MCAP chunk record with the given claim (the inner records are not checked
    before the data inflates)."""
    body = (struct.pack("<QQQI", 0, 0, uncompressed_size, 0)
            + struct.pack("<I", len(compression)) + compression.encode()
            + struct.pack("<Q", len(data)) + data)
    return bytes([0x06]) + struct.pack("<Q", len(body)) + body


def _peak_mb_reading(path) -> tuple[int, float]:
    """(messages read, peak RSS in MB) of reading ``path`` in a child process."""
    # the peak of the child's own memory (VmHWM): ru_maxrss keeps, across the exec, the
    # peak of the process it was forked from (pytest, 588 MB late in a whole run)
    code = ("import re, sys\n"
            "from formation_ilc.recordings.mcap_io import read_messages, ReadReport\n"
            "rep = ReadReport()\n"
            "n = sum(1 for _ in read_messages(sys.argv[1], report=rep))\n"
            "hwm = re.search(r'VmHWM:\\s*(\\d+)', open('/proc/self/status').read())\n"
            "print(n, len(rep.damage), hwm.group(1))")
    res = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True,
                         text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    n, damaged, kb = map(int, res.stdout.split())
    assert damaged == 1
    return n, kb / 1024


@pytest.mark.parametrize("claim, real", [(1 << 40, 1 << 20),      # a lie of a terabyte
                                         (200 << 20, 1 << 20),     # inflates to less
                                         (2 << 30, 2 << 30)])      # a real 2 GiB bomb
def test_a_chunk_whose_size_lies_or_that_is_a_bomb_costs_no_memory(tmp_path, claim, real):
    import zstandard

    good = tmp_path / "good.mcap"
    _write(good, 10, 100, chunk=1 << 20)
    raw = good.read_bytes()
    # a zstd frame of ``real`` zeros, written without its content size, in pieces
    cz = zstandard.ZstdCompressor(write_content_size=False).compressobj()
    frame = b"".join(cz.compress(bytes(1 << 24)) for _ in range(real >> 24)) if real >= 1 << 24 \
        else cz.compress(bytes(real))
    frame += cz.flush()
    bomb = _chunk_record(claim, "zstd", frame)
    at = raw.index(bytes([0x06]), 8)  # before the file's own chunk
    path = tmp_path / "bomb.mcap"
    path.write_bytes(raw[:at] + bomb + raw[at:])
    n, peak = _peak_mb_reading(path)
    assert n == 10            # the file's own chunk still reads
    assert peak < 400, f"peak RSS {peak:.0f} MB"

