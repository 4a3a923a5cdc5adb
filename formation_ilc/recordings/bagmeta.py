"""rosbag2's ``metadata.yaml`` for a recording: its folder opens as a rosbag2 bag.

``ros2 bag info DIR``, ``ros2 bag play DIR`` and rosbags' ``Reader(DIR)`` open a folder by
its ``metadata.yaml``: the storage (``mcap``), the files, and every topic with its type,
serialization format, offered QoS, type hash and message count. Written here from the MCAP
file's own summary (its channels carry rosbag2's ``offered_qos_profiles`` and
``topic_type_hash`` metadata, its statistics the counts and times), in the format rosbag2
of ROS 2 Jazzy writes and reads: version 9 (QoS profiles as a YAML list, the type
description hashes, ``ros_distro``). A recording in several files (a restarted recorder's
parts, ``recordings.recording.recording_parts``) is one bag of them all; a file without a
summary (a killed recorder's) is left out. Written atomically.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from formation_ilc.store.atomic import atomic_write_text

__all__ = ["METADATA", "VERSION", "bag_metadata", "write_bag_metadata"]

#: the file rosbag2 looks for in a bag's folder
METADATA = "metadata.yaml"
#: rosbag2's metadata version of ROS 2 Jazzy
VERSION = 9


def _summary(path: Path) -> Any:
    from mcap.reader import make_reader

    try:
        with path.open("rb") as f:
            summary = make_reader(f).get_summary()
    except Exception:  # noqa: BLE001 - a damaged file: no summary to describe
        return None
    return summary if summary is not None and summary.statistics is not None else None


def bag_metadata(mcap_paths: Sequence[str | Path]) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` of a recording's MCAP files (one folder; a
    restarted recorder's parts after the first), their paths relative to the folder. A
    file without a summary (its recorder was killed) is left out: tools could not read
    it. ValueError when none has one."""
    files: list = []
    topics: dict[tuple[str, str], dict[str, Any]] = {}
    order: list[tuple[str, str]] = []
    for path in map(Path, mcap_paths):
        summary = _summary(path)
        if summary is None:
            continue
        st = summary.statistics
        start = int(st.message_start_time) if st.message_count else 0
        end = int(st.message_end_time) if st.message_count else 0
        files.append((path.name, start, end, int(st.message_count)))
        for cid, ch in sorted(summary.channels.items()):
            schema = summary.schemas.get(ch.schema_id)
            key = (ch.topic, schema.name if schema is not None else "")
            if key not in topics:
                order.append(key)
                qos = yaml.safe_load(ch.metadata.get("offered_qos_profiles", "") or "[]") or []
                topics[key] = {"topic_metadata": {
                    "name": key[0], "type": key[1],
                    "serialization_format": ch.message_encoding or "cdr",
                    "offered_qos_profiles": qos,
                    "type_description_hash": ch.metadata.get("topic_type_hash", "")},
                    "message_count": 0}
            topics[key]["message_count"] += int(st.channel_message_counts.get(cid, 0))
    if not files:
        raise ValueError(f"{', '.join(map(str, mcap_paths))}: no summary (the recording was "
                         f"not closed)")
    counted = [f for f in files if f[3]]
    start = min((f[1] for f in counted), default=0)
    end = max((f[2] for f in counted), default=0)
    return {"version": VERSION, "storage_identifier": "mcap",
            "duration": {"nanoseconds": end - start},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": sum(f[3] for f in files),
            "topics_with_message_count": [topics[k] for k in order],
            "compression_format": "", "compression_mode": "",
            "relative_file_paths": [f[0] for f in files],
            "files": [{"path": name, "starting_time": {"nanoseconds_since_epoch": s0},
                       "duration": {"nanoseconds": e0 - s0}, "message_count": n}
                      for name, s0, e0, n in files],
            "custom_data": None, "ros_distro": "jazzy"}


def write_bag_metadata(mcap_paths: str | Path | Sequence[str | Path]) -> Path:
    """Write ``metadata.yaml`` beside the recording's MCAP file(s) (replacing one there);
    its path."""
    paths = [Path(mcap_paths)] if isinstance(mcap_paths, (str, Path)) else list(
        map(Path, mcap_paths))
    out = paths[0].parent / METADATA
    text = yaml.safe_dump({"rosbag2_bagfile_information": bag_metadata(paths)},
                          sort_keys=False, default_flow_style=False)
    atomic_write_text(out, text)
    return out
