"""MCAP written by formation_ilc.recordings.mcap_io reads back with two independent readers, a
file cut short by a kill reads back up to the cut and can be repaired, and the schemas and
type hashes are the bytes rosbag2 and rclpy give."""

import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path as Path_

import pytest
import yaml

pytest.importorskip("mcap_ros2")  # the [mcap] extra; CI installs it
from geometry_msgs.msg import PoseStamped, Twist  # noqa: E402
from nav_msgs.msg import Path  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402

import msgs_schema as ms  # noqa: E402
from formation_ilc.recordings.mcap_io import (  # noqa: E402
    RosMcapWriter,
    bag_metadata,
    message_definition,
    qos_yaml,
    read_messages,
    read_metadata,
    repair,
    type_hash,
)

from .rosbag2_jazzy import INFINITE, BadConversion, check_file, decode_bag_metadata  # noqa: E402


def _path(n: int, k: int) -> Path:
    p = Path()
    p.header.frame_id = "robot_1"
    p.header.stamp.sec = k
    for i in range(n):
        ps = PoseStamped()
        ps.header.stamp.nanosec = i
        ps.pose.position.x = float(i) + 0.25
        ps.pose.orientation.w = 1.0
        p.poses.append(ps)
    return p


def test_roundtrip_with_mcap_ros2_and_rosbags(tmp_path):
    f = tmp_path / "run.mcap"
    tw = Twist()
    tw.linear.x = 0.5
    tw.angular.z = -0.25
    with RosMcapWriter(f) as w:
        w.channel("/formation/robot_1/cmd_vel", "geometry_msgs/msg/Twist", qos_yaml())
        w.channel("/formation/robot_1/trajectory", "nav_msgs/msg/Path",
                  qos_yaml(durability="transient_local", depth=1))
        w.metadata("formation_ilc", {"scenario": "name: x"})
        for k in range(3):
            w.write("/formation/robot_1/cmd_vel", serialize_message(tw), 100 + k, 50 + k)
            w.write("/formation/robot_1/trajectory", serialize_message(_path(5, k)), 200 + k,
                    150 + k)

    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with f.open("rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        decoded = list(reader.iter_decoded_messages())
        summary = reader.get_summary()
    assert len(decoded) == 6
    schema, channel, message, msg = next(d for d in decoded if d[1].topic.endswith("trajectory"))
    assert schema.name == "nav_msgs/msg/Path" and schema.encoding == "ros2msg"
    assert channel.message_encoding == "cdr"
    assert "reliability: reliable" in channel.metadata["offered_qos_profiles"]
    assert msg.poses[3].pose.position.x == 3.25 and message.log_time == 200
    assert message.publish_time == 150
    assert summary.statistics.message_count == 6

    from rosbags.highlevel import AnyReader

    with AnyReader([f]) as ar:
        conns = {c.topic: c for c in ar.connections}
        assert conns["/formation/robot_1/cmd_vel"].msgtype == "geometry_msgs/msg/Twist"
        qos = conns["/formation/robot_1/trajectory"].ext.offered_qos_profiles[0]
        assert qos.durability.name == "TRANSIENT_LOCAL" and qos.depth == 1
        got = [ar.deserialize(raw, c.msgtype) for c, _, raw in ar.messages()]
    assert got[0].linear.x == 0.5 and got[0].angular.z == -0.25  # log-time order
    assert len(got[3].poses) == 5 and got[3].poses[4].pose.position.x == 4.25
    assert read_metadata(f)["formation_ilc"]["scenario"] == "name: x"
    # rosbag2's own record, decoded with rosbag2 Jazzy's rules: what `ros2 bag info` and
    # `ros2 bag play` read on opening the file (distro, counts per topic, span, QoS)
    bag = check_file(f)
    assert bag["message_count"] == 6 and bag["files"][0]["message_count"] == 6
    counts = {t["topic_metadata"]["name"]: t["message_count"]
              for t in bag["topics_with_message_count"]}
    assert counts == {"/formation/robot_1/cmd_vel": 3, "/formation/robot_1/trajectory": 3}
    assert bag["duration"] == 202 - 100 and bag["starting_time"] == 100
    qos = {t["topic_metadata"]["name"]: t["topic_metadata"]["offered_qos_profiles"]
           for t in bag["topics_with_message_count"]}
    assert qos["/formation/robot_1/trajectory"] == [{
        "history": "keep_last", "depth": 1, "reliability": "reliable",
        "durability": "transient_local", "liveliness": "automatic",
        "deadline": INFINITE_T, "lifespan": INFINITE_T, "liveliness_lease_duration": INFINITE_T,
        "avoid_ros_namespace_conventions": False}]
    # a repaired copy leaves the record out rather than copy the original's counts
    repair(f, tmp_path / "copy.mcap")
    assert "rosbag2" not in read_metadata(tmp_path / "copy.mcap")
    assert read_metadata(tmp_path / "copy.mcap")["formation_ilc"]["scenario"] == "name: x"


INFINITE_T = (INFINITE["sec"], INFINITE["nsec"])


def test_rosbag2_rules_refuse_what_rosbag2_refuses():
    """The decoder is rosbag2's: the shape issue 40 found (a version-9 record whose QoS is
    one YAML string) throws, and so do wrong scalar types."""
    good = bag_metadata("x.mcap", {"/t": ["std_msgs/msg/String", qos_yaml(), "RIHS01_ab", 2]},
                        [5, 9])
    assert decode_bag_metadata(good)["topics_with_message_count"][0]["message_count"] == 2
    doc = yaml.safe_load(good)
    as_string = dict(doc)
    as_string["topics_with_message_count"] = [
        {"topic_metadata": {**t["topic_metadata"], "offered_qos_profiles": qos_yaml()},
         "message_count": t["message_count"]} for t in doc["topics_with_message_count"]]
    with pytest.raises(BadConversion, match="offered_qos_profiles: not a sequence"):
        decode_bag_metadata(yaml.safe_dump(as_string))
    for key, value, why in (("message_count", -1, "negative"), ("version", "nine", "integer"),
                            ("duration", 5, "not a map"), ("relative_file_paths", "x.mcap",
                                                            "not a sequence")):
        with pytest.raises(BadConversion, match=why):
            decode_bag_metadata(yaml.safe_dump({**doc, key: value}))
    del doc["ros_distro"]
    with pytest.raises(BadConversion, match="ros_distro: missing"):
        decode_bag_metadata(yaml.safe_dump(doc))


WRITER = textwrap.dedent("""
    import sys, time
    from std_msgs.msg import String
    from rclpy.serialization import serialize_message
    from formation_ilc.recordings.mcap_io import RosMcapWriter, qos_yaml
    w = RosMcapWriter(sys.argv[1], flush_period=0.05, chunk_size=1 << 30)
    w.channel("/t", "std_msgs/msg/String", qos_yaml())
    i = 0
    while True:
        m = String(); m.data = str(i)
        w.write("/t", serialize_message(m), i, i)
        i += 1
        if i == 200:
            print("ready", flush=True)
        time.sleep(0.001)
""")


def test_killed_writer_leaves_readable_file_and_repair_completes_it(tmp_path):
    f = tmp_path / "cut.mcap"
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(f)], stdout=subprocess.PIPE,
                            text=True)
    try:
        # 200 messages at >= 1 ms each with a 50 ms flush period: several flushes done
        assert proc.stdout.readline().strip() == "ready"
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    msgs = list(read_messages(f))
    assert len(msgs) >= 100  # everything flushed before the kill
    from rclpy.serialization import deserialize_message
    from std_msgs.msg import String

    values = [int(deserialize_message(m.data, String).data) for m in msgs]
    assert values == list(range(len(values)))  # in order, none lost before the cut

    fixed = tmp_path / "fixed.mcap"
    assert repair(f, fixed) == len(values)
    from mcap.reader import make_reader

    with fixed.open("rb") as fh:
        reader = make_reader(fh)
        assert reader.get_summary().statistics.message_count == len(values)
    with pytest.raises(ValueError):
        repair(fixed, fixed)


# --------------------------------------------------------------------------- schemas

#: every type the recorder and the batch simulator record (msgs_schema.topic_table)
RECORDED_TYPES = sorted({typ for _, typ, _ in ms.topic_table(3)})
#: the schema bytes this project wrote before rosbags' .msg parser found the dependencies
#: (the installed .msg texts, comments included, concatenated as rosbag2 does)
DEFINITIONS = json.loads((Path_(__file__).parent / "data" / "message_definitions.json")
                         .read_text())


def test_schemas_keep_the_bytes_written_before(tmp_path):
    assert sorted(DEFINITIONS) == RECORDED_TYPES
    f = tmp_path / "s.mcap"
    with RosMcapWriter(f) as w:
        for i, typ in enumerate(RECORDED_TYPES):
            w.channel(f"/t{i}", typ, qos_yaml())
    from mcap.reader import make_reader

    with f.open("rb") as fh:
        schemas = make_reader(fh).get_summary().schemas.values()
    assert {s.name: s.data for s in schemas} == {t: d.encode() for t, d in DEFINITIONS.items()}
    assert all(s.encoding == "ros2msg" for s in schemas)
    # the short form of a type name gives the same text
    assert message_definition("nav_msgs/Path") == DEFINITIONS["nav_msgs/msg/Path"]


@pytest.mark.ros
def test_type_hashes_are_rclpys(context):
    """``type_hash`` of every recorded type is what rclpy reports for a writer of it (and
    what the stack's recorder writes into its channels)."""
    import importlib

    import rclpy

    node = rclpy.create_node("hashes", context=context)
    try:
        for i, typ in enumerate(RECORDED_TYPES):
            pkg, _, name = typ.split("/")
            node.create_publisher(getattr(importlib.import_module(f"{pkg}.msg"), name),
                                  f"/hash_{i}", 1)
            (info,) = node.get_publishers_info_by_topic(f"/hash_{i}")
            assert type_hash(typ) == str(info.topic_type_hash), typ
    finally:
        node.destroy_node()
