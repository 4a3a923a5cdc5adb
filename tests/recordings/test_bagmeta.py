"""rosbag2's metadata.yaml of a recording's folder (``recordings.bagmeta``): rosbags opens
the folder as a bag of every part that has a summary, with each topic's count summed."""

from __future__ import annotations

import yaml

from formation_ilc.recordings import cdr
from formation_ilc.recordings.bagmeta import bag_metadata, write_bag_metadata
from formation_ilc.recordings.mcap_io import RosMcapWriter, qos_yaml, type_hash
from formation_ilc.recordings.recording import recording_parts


def _file(path, topics: dict[str, int], t0: int) -> None:
    with RosMcapWriter(path) as w:
        for topic in topics:
            w.channel(topic, "std_msgs/msg/String",
                      qos_yaml(durability="transient_local"), type_hash("std_msgs/msg/String"))
        t = t0
        for topic, n in topics.items():
            for k in range(n):
                t += 1_000
                w.write(topic, cdr.encode_string(f"{topic} {k}"), t, t)


def test_a_recording_in_parts_is_one_bag_of_its_readable_files(tmp_path):
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag2 import Reader

    first, part, killed = (tmp_path / n for n in ("run.mcap", "run.part1.mcap",
                                                  "run.part2.mcap"))
    _file(first, {"/a": 3, "/b": 2}, 10_000)
    _file(part, {"/a": 4}, 50_000)
    _file(killed, {"/a": 5}, 90_000)
    killed.write_bytes(killed.read_bytes()[:200])  # a killed recorder: no summary
    parts = recording_parts(first)
    assert parts == [first, part, killed]
    meta = yaml.safe_load(write_bag_metadata(parts).read_text())["rosbag2_bagfile_information"]
    assert meta == {"rosbag2_bagfile_information": bag_metadata(parts)}[
        "rosbag2_bagfile_information"]
    assert meta["version"] == 9 and meta["storage_identifier"] == "mcap"
    assert meta["relative_file_paths"] == ["run.mcap", "run.part1.mcap"]
    assert meta["message_count"] == 9
    counts = {t["topic_metadata"]["name"]: t["message_count"]
              for t in meta["topics_with_message_count"]}
    assert counts == {"/a": 7, "/b": 2}
    (t,) = [t for t in meta["topics_with_message_count"] if t["topic_metadata"]["name"] == "/a"]
    assert t["topic_metadata"]["offered_qos_profiles"][0]["durability"] == "transient_local"
    assert t["topic_metadata"]["type_description_hash"] == type_hash("std_msgs/msg/String")
    with Reader(tmp_path) as bag:  # rosbags reads the folder by its metadata.yaml
        assert bag.message_count == 9
        assert sum(1 for _ in bag.messages()) == 9
    with AnyReader([tmp_path]) as ar:
        got = [ar.deserialize(raw, c.msgtype).data for c, _, raw in ar.messages()]
    assert sorted(got)[:3] == ["/a 0", "/a 0", "/a 1"]
