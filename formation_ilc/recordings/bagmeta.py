"""rosbag2's ``metadata.yaml`` for a recording: its folder opens as a rosbag2 bag.

``ros2 bag info DIR``, ``ros2 bag play DIR`` and rosbags' ``Reader(DIR)`` open a folder by
its ``metadata.yaml``: the storage (``mcap``), the files, and every topic with its type,
serialization format, offered QoS, type hash and message count. Written here from the MCAP
file's own summary (its channels carry rosbag2's ``offered_qos_profiles`` and
``topic_type_hash`` metadata, its statistics the counts and times), in the format rosbag2
of ROS 2 Jazzy writes and reads: version 9 (QoS profiles as a YAML list, the type
description hashes, ``ros_distro``). Written atomically; a recording that cannot be read
(no summary: a crashed writer) gets none.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from formation_ilc.store.atomic import atomic_write_text

__all__ = ["METADATA", "VERSION", "bag_metadata", "write_bag_metadata"]

#: the file rosbag2 looks for in a bag's folder
METADATA = "metadata.yaml"
#: rosbag2's metadata version of ROS 2 Jazzy
VERSION = 9


def bag_metadata(mcap_path: str | Path) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` of the MCAP file ``mcap_path``, its path
    relative to its folder; ValueError for a file without a summary."""
    from mcap.reader import make_reader

    path = Path(mcap_path)
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    if summary is None or summary.statistics is None:
        raise ValueError(f"{path}: no summary (the recording was not closed)")
    st = summary.statistics
    start = int(st.message_start_time) if st.message_count else 0
    duration = int(st.message_end_time - st.message_start_time) if st.message_count else 0
    topics = []
    for cid, ch in sorted(summary.channels.items()):
        schema = summary.schemas.get(ch.schema_id)
        qos = yaml.safe_load(ch.metadata.get("offered_qos_profiles", "") or "[]") or []
        topics.append({"topic_metadata": {
            "name": ch.topic, "type": schema.name if schema is not None else "",
            "serialization_format": ch.message_encoding or "cdr",
            "offered_qos_profiles": qos,
            "type_description_hash": ch.metadata.get("topic_type_hash", "")},
            "message_count": int(st.channel_message_counts.get(cid, 0))})
    return {"version": VERSION, "storage_identifier": "mcap",
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": int(st.message_count),
            "topics_with_message_count": topics,
            "compression_format": "", "compression_mode": "",
            "relative_file_paths": [path.name],
            "files": [{"path": path.name, "starting_time": {"nanoseconds_since_epoch": start},
                       "duration": {"nanoseconds": duration},
                       "message_count": int(st.message_count)}],
            "custom_data": None, "ros_distro": "jazzy"}


def write_bag_metadata(mcap_path: str | Path) -> Path:
    """Write ``metadata.yaml`` beside ``mcap_path`` (replacing one there); its path."""
    path = Path(mcap_path)
    out = path.parent / METADATA
    text = yaml.safe_dump({"rosbag2_bagfile_information": bag_metadata(path)},
                          sort_keys=False, default_flow_style=False)
    atomic_write_text(out, text)
    return out
