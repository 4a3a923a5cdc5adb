"""CDR (XCDR1, little endian) encoding of the few messages the batch simulator records.

The distributed stack serialises with rclpy; the batch simulator writes the same messages
without ROS, thousands of whole-trial paths per run, so it packs them with numpy here.
Kept over a library because it is much faster: scripts/bench_cdr.py, a 141-pose
nav_msgs/msg/Path (one robot's trial) on 2 cores shared with other work, medians of 7,
measured 0.14-0.16 ms per message here, 10-11 ms building the message and serialising it
with rclpy (65-76x) and 6-7 ms with rosbags' ``serialize_cdr`` (38-47x). Decoding
(``decode_path``) is the same idea for analyze. tests/recordings/test_cdr.py checks the
bytes against rclpy's serialiser.
"""

from __future__ import annotations

import struct

import numpy as np
from numpy.typing import NDArray

__all__ = ["encode_path", "encode_pose_stamped", "encode_string", "encode_twist",
           "encode_clock", "encode_diagnostic_array", "decode_path"]

_ENCAPSULATION = b"\x00\x01\x00\x00"  # CDR_LE


def _sec_nsec(ns: int) -> tuple[int, int]:
    sec, nsec = divmod(int(ns), 1_000_000_000)
    return sec, nsec


def _string(buf: bytearray, text: str) -> None:
    _align(buf, 4)
    raw = text.encode() + b"\x00"
    buf += struct.pack("<I", len(raw)) + raw


def _align(buf: bytearray, n: int) -> None:
    # alignment is relative to the data, after the 4-byte encapsulation header
    pad = (-(len(buf) - 4)) % n
    buf += b"\x00" * pad


def _pose_fields(eta: NDArray[np.float64]) -> NDArray[np.float64]:
    """(S, 7): x, y, z, qx, qy, qz, qw of planar outputs eta (S, 3)."""
    out = np.zeros((len(eta), 7))
    out[:, 0] = eta[:, 0]
    out[:, 1] = eta[:, 1]
    out[:, 5] = np.sin(0.5 * eta[:, 2])
    out[:, 6] = np.cos(0.5 * eta[:, 2])
    return out


def _stamped_pose(buf: bytearray, stamp_ns: int, frame: str, fields: NDArray[np.float64]
                  ) -> None:
    _align(buf, 4)
    buf += struct.pack("<iI", *_sec_nsec(stamp_ns))
    _string(buf, frame)
    _align(buf, 8)
    buf += fields.astype("<f8").tobytes()


def encode_pose_stamped(eta: NDArray[np.float64], stamp_ns: int, frame: str) -> bytes:
    """geometry_msgs/msg/PoseStamped of a planar output eta (3,)."""
    buf = bytearray(_ENCAPSULATION)
    _stamped_pose(buf, stamp_ns, frame, _pose_fields(np.asarray(eta, dtype=float)[None])[0])
    return bytes(buf)


def encode_path(eta: NDArray[np.float64], stamps_ns: NDArray[np.int64], frame: str,
                stamp_ns: int) -> bytes:
    """nav_msgs/msg/Path: header (stamp_ns, frame) and one PoseStamped per sample, each
    stamped with its label and in ``frame``. eta : shape (S, 3); stamps_ns : shape (S,)."""
    eta = np.asarray(eta, dtype=float)
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    n = len(eta)
    buf = bytearray(_ENCAPSULATION)
    buf += struct.pack("<iI", *_sec_nsec(stamp_ns))
    _string(buf, frame)
    _align(buf, 4)
    buf += struct.pack("<I", n)
    if n == 0:
        return bytes(buf)
    fields = _pose_fields(eta)
    _stamped_pose(buf, int(stamps[0]), frame, fields[0])
    if n == 1:
        return bytes(buf)
    # every later element starts 8-aligned (the previous one ends with float64s), so they
    # share one layout: pack them as a structured array
    assert (len(buf) - 4) % 8 == 0
    raw = frame.encode() + b"\x00"
    head = 12 + len(raw)
    pad = (-head) % 8
    dtype = np.dtype({"names": ["sec", "nsec", "len", "frame", "pose"],
                      "formats": ["<i4", "<u4", "<u4", f"S{len(raw)}", ("<f8", (7,))],
                      "offsets": [0, 4, 8, 12, head + pad],
                      "itemsize": head + pad + 56})
    rest = np.zeros(n - 1, dtype=dtype)
    sec, nsec = np.divmod(stamps[1:], 1_000_000_000)
    rest["sec"] = sec
    rest["nsec"] = nsec
    rest["len"] = len(raw)
    rest["frame"] = raw
    rest["pose"] = fields[1:]
    return bytes(buf) + rest.tobytes()


def encode_string(text: str) -> bytes:
    """std_msgs/msg/String."""
    buf = bytearray(_ENCAPSULATION)
    _string(buf, text)
    return bytes(buf)


def encode_diagnostic_array(stamp_ns: int, statuses: list[tuple[int, str, str, str,
                                                                list[tuple[str, str]]]]
                            ) -> bytes:
    """diagnostic_msgs/msg/DiagnosticArray of (level, name, message, hardware_id, [(key,
    value)]) statuses, the frame empty."""
    buf = bytearray(_ENCAPSULATION)
    buf += struct.pack("<iI", *_sec_nsec(stamp_ns))
    _string(buf, "")
    _align(buf, 4)
    buf += struct.pack("<I", len(statuses))
    for level, name, message, hardware_id, values in statuses:
        buf += bytes([level])
        for text in (name, message, hardware_id):
            _string(buf, text)
        _align(buf, 4)
        buf += struct.pack("<I", len(values))
        for key, value in values:
            _string(buf, key)
            _string(buf, value)
    return bytes(buf)


def encode_twist(v: float, w: float) -> bytes:
    """geometry_msgs/msg/Twist with linear.x = v, angular.z = w."""
    return _ENCAPSULATION + struct.pack("<6d", float(v), 0.0, 0.0, 0.0, 0.0, float(w))


def encode_clock(ns: int) -> bytes:
    """rosgraph_msgs/msg/Clock."""
    return _ENCAPSULATION + struct.pack("<iI", *_sec_nsec(ns))


def decode_path(data: bytes) -> tuple[NDArray[np.float64], NDArray[np.int64], str, int]:
    """Fast reading of a nav_msgs/msg/Path whose poses all carry the header's frame_id.

    Returns (fields (S, 7): x, y, z, qx, qy, qz, qw; stamps (S,) [ns]; frame; header stamp
    [ns]). ValueError if the bytes are not such a Path (the caller then falls back to the
    general deserialiser).
    """
    if data[:4] != _ENCAPSULATION:
        raise ValueError("not little-endian CDR")
    mv = memoryview(data)[4:]
    sec, nsec = struct.unpack_from("<iI", mv, 0)
    (flen,) = struct.unpack_from("<I", mv, 8)
    raw = bytes(mv[12:12 + flen])
    if not raw.endswith(b"\x00"):
        raise ValueError("bad string")
    pos = 12 + flen
    pos += (-pos) % 4
    (n,) = struct.unpack_from("<I", mv, pos)
    pos += 4
    if n * 68 > len(mv) - pos:  # a pose takes at least a header and 7 float64s
        raise ValueError(f"{n} poses cannot fit in {len(mv) - pos} bytes")
    fields = np.empty((n, 7))
    stamps = np.empty(n, dtype=np.int64)
    if n:
        s0, ns0, l0 = struct.unpack_from("<iII", mv, pos)
        if ns0 >= 1_000_000_000:
            raise ValueError("stamp nanosec outside [0, 1e9)")
        if bytes(mv[pos + 12:pos + 12 + l0]) != raw:
            raise ValueError("pose frame differs from the path's")
        p = pos + 12 + l0
        p += (-p) % 8
        fields[0] = np.frombuffer(mv, "<f8", 7, p)
        stamps[0] = s0 * 1_000_000_000 + ns0
        p += 56
        if n > 1:
            head = 12 + flen
            pad = (-head) % 8
            size = head + pad + 56
            if len(mv) - p != (n - 1) * size:
                raise ValueError("poses of different layouts")
            dtype = np.dtype({"names": ["sec", "nsec", "len", "frame", "pose"],
                              "formats": ["<i4", "<u4", "<u4", f"S{flen}", ("<f8", (7,))],
                              "offsets": [0, 4, 8, 12, head + pad], "itemsize": size})
            rest = np.frombuffer(mv, dtype, n - 1, p)
            if (rest["len"] != flen).any() or (rest["frame"] != raw.rstrip(b"\x00")).any():
                raise ValueError("pose frame differs from the path's")
            if (rest["nsec"] >= 1_000_000_000).any():
                raise ValueError("stamp nanosec outside [0, 1e9)")
            fields[1:] = rest["pose"]
            stamps[1:] = rest["sec"].astype(np.int64) * 1_000_000_000 + rest["nsec"]
    return fields, stamps, raw[:-1].decode(), sec * 1_000_000_000 + nsec
