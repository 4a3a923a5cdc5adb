"""Runs recorded to MCAP and analysed from the recording alone.

A real multi-process launch with --record: `analyze` reproduces the launcher's per-trial
errors exactly; two independent readers open the file; a SIGKILLed recorder leaves a file
that reads back up to the kill (and mcap-repair completes it). The batch simulator's
recording analyses to the simulator's own metrics.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections import Counter

import numpy as np
import pytest
import yaml

pytest.importorskip("mcap_ros2")  # the [mcap] extra; CI installs it

from formation_ilc.cli import main  # noqa: E402
from formation_ilc.config.scenario import load_scenario  # noqa: E402
from formation_ilc.core.metrics import read_metrics  # noqa: E402
from formation_ilc.model.simulate import simulate  # noqa: E402
from formation_ilc.recordings.mcap_io import read_messages, type_hash  # noqa: E402
from formation_ilc.recordings.recording import load_recording  # noqa: E402

from ..procs import find_child, stop_group  # noqa: E402
from ..recordings.rosbag2_jazzy import check_file  # noqa: E402
from .test_stack import launch  # noqa: E402


@pytest.mark.ros
@pytest.mark.multiprocess
def test_launch_record_then_analyze_reproduces_the_launcher_exactly(ros_env, tmp_path):
    rec = tmp_path / "run.mcap"
    res = launch(ros_env, tmp_path / "launch", "paper-triangle3", "--trials", "4", "--seed",
                 "3", "--record", str(rec))
    assert res.returncode == 0, res.stdout
    launched = read_metrics(tmp_path / "launch" / "metrics.csv")
    assert len(launched) == 4

    assert main(["analyze", str(rec), "--out", str(tmp_path / "an")]) == 0
    analysed = read_metrics(tmp_path / "an" / "metrics.csv")
    np.testing.assert_array_equal(analysed, launched)  # exactly: same bytes, same decode
    for f in ("report.html", "errors.png", "trajectories.png", "formation.png", "delays.png"):
        assert (tmp_path / "an" / f).stat().st_size > 5_000, f

    # self-contained: the scenario, the trial boundaries, the measured delays
    r = load_recording(rec)
    assert r.scenario.name == "paper-triangle3" and r.scenario.seed == 3
    starts = [e["trial"] for e in r.events if e["event"] == "start"]
    ends = [e["trial"] for e in r.events if e["event"] == "end"]
    assert starts == ends == [0, 1, 2, 3]
    assert set(r.delays) == {"leader->robot_1", "robot_1->robot_2", "robot_1->robot_3"}
    assert r.delays == r.injected  # lockstep: what the robots measure is what was injected
    n_deliveries = sum(sum(h.values()) for h in r.delays.values())
    assert n_deliveries > 3 * 4 * 130

    # every per-sample topic, every sample (nothing lost by a late recorder)
    counts = Counter(m.topic for m in read_messages(rec))
    for i in (1, 2, 3):
        assert counts[f"/formation/robot_{i}/pose"] == 4 * 141
        assert counts[f"/formation/robot_{i}/cmd_vel"] == 4 * 140
        # a shared pose is the robot's pose re-sent bit for bit: recorded once, as the pose
        assert counts[f"/formation/robot_{i}/shared_pose"] == 0
        assert counts[f"/formation/robot_{i}/trajectory"] == 4
    assert counts["/clock"] == 4 * 141

    # reader 1: mcap + mcap-ros2-support, with the rosbag2 channel metadata
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with rec.open("rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        for ch in summary.channels.values():
            assert ch.message_encoding == "cdr"
            assert "reliability: reliable" in ch.metadata["offered_qos_profiles"]
            assert ch.metadata["topic_type_hash"].startswith("RIHS01_")
            assert ch.metadata["topic_type_hash"] == type_hash(summary.schemas[ch.schema_id].name)
            assert summary.schemas[ch.schema_id].encoding == "ros2msg"
        poses = [(m, msg) for _, _, m, msg in reader.iter_decoded_messages(
            topics=["/formation/robot_2/pose"])]
    assert len(poses) == 4 * 141
    m, msg = poses[5]
    stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
    assert m.publish_time == stamp  # publish time = send label
    assert msg.header.frame_id == "map"  # REP-105: the world frame; the topic names the robot

    # rosbag2's record, as `ros2 bag info` / `play` decode it; the writers' QoS as the graph
    # reported it (history and depth unknown to the graph, times infinite)
    bag = check_file(rec)
    qos = bag["topics_with_message_count"][0]["topic_metadata"]["offered_qos_profiles"][0]
    assert qos["history"] == "unknown" and qos["deadline"] == (9223372036, 854775807)

    # reader 2: rosbags
    from rosbags.highlevel import AnyReader

    with AnyReader([rec]) as ar:
        conns = [c for c in ar.connections if c.topic == "/formation/robot_1/trajectory"]
        assert conns[0].msgtype == "nav_msgs/msg/Path"
        paths = [ar.deserialize(raw, c.msgtype) for c, _, raw in ar.messages(connections=conns)]
    assert len(paths) == 4 and len(paths[0].poses) == 141
    check_frames_and_bag(rec, n=3, samples=4 * 141)


def check_frames_and_bag(rec, n: int, samples: int) -> None:
    """The recording's frames (issue 54), decoded as tf2_msgs/msg/TFMessage by rosbags'
    own ROS 2 Jazzy types: one tree from map reaching every robot's base_link through its
    odom, the leader's frame under map, a transform of every robot each sample; each
    robot's robot_description a URDF (as PyBullet's parser loads it) whose link is that
    base_link; and the recording's folder opens as a rosbag2 bag by its metadata.yaml."""
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    jazzy = get_typestore(Stores.ROS2_JAZZY)
    parents: dict[str, str] = {}
    base_links: Counter[str] = Counter()
    with AnyReader([rec], default_typestore=jazzy) as ar:
        conns = [c for c in ar.connections if c.topic in ("/tf", "/tf_static")]
        assert {c.topic for c in conns} == {"/tf", "/tf_static"}
        assert {c.msgtype for c in conns} == {"tf2_msgs/msg/TFMessage"}
        for c, _, raw in ar.messages(connections=conns):
            for tr in jazzy.deserialize_cdr(raw, c.msgtype).transforms:
                parents[tr.child_frame_id] = tr.header.frame_id
                base_links[tr.child_frame_id] += tr.child_frame_id.endswith("/base_link")
    roots = set()
    for i in range(1, n + 1):
        frame, chain = f"robot_{i}/base_link", []
        while frame in parents:
            chain.append(frame)
            frame = parents[frame]
        assert chain == [f"robot_{i}/base_link", f"robot_{i}/odom"], parents
        roots.add(frame)
        assert base_links[f"robot_{i}/base_link"] >= samples  # resent samples too
    assert roots == {"map"} and parents["leader"] == "map"
    from ..config.test_urdf import load_urdf

    urdfs = {m.topic: m.data for m in read_messages(rec) if m.topic.endswith("/robot_description")}
    assert set(urdfs) == {f"/formation/robot_{i}/robot_description" for i in range(1, n + 1)}
    for topic, data in urdfs.items():
        text = jazzy.deserialize_cdr(data, "std_msgs/msg/String").data
        assert load_urdf(text, rec.parent)[0] == f"{topic.split('/')[2]}/base_link"
    # the folder: rosbag2's metadata.yaml beside the MCAP, as rosbags reads a bag
    meta = yaml.safe_load((rec.parent / "metadata.yaml").read_text())
    assert meta["rosbag2_bagfile_information"]["relative_file_paths"] == [rec.name]
    assert meta["rosbag2_bagfile_information"]["version"] == 9  # what Jazzy writes
    with Reader(rec.parent) as bag:
        assert bag.message_count == sum(1 for _ in read_messages(rec))
        assert {c.topic for c in bag.connections} >= {"/tf", "/tf_static", "/clock"}


@pytest.mark.ros
@pytest.mark.multiprocess
def test_sigkill_of_the_recorder_keeps_what_was_written(ros_env, tmp_path):
    rec = tmp_path / "run.mcap"
    out = tmp_path / "launch"
    argv = [sys.executable, "-m", "formation_ilc.cli", "launch", "paper-triangle3",
            "--trials", "40", "--out", str(out), "--domain-id", ros_env["ROS_DOMAIN_ID"],
            "--no-plots", "--timeout", "20", "--record", str(rec)]
    proc = subprocess.Popen(argv, env=ros_env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        lines = []
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            lines.append(line)
            if line.startswith("trial 3 of 0..39"):
                break
        assert lines[-1].startswith("trial 3 of 0..39"), "".join(lines)
        pid = find_child(ros_env["ROS_DOMAIN_ID"], f"formation_ilc.nodes.recorder --output {rec}",
                         time.monotonic() + 10)
        os.kill(pid, signal.SIGKILL)
        stdout, _ = proc.communicate(timeout=60)
    finally:
        stop_group(proc, signal.SIGKILL)
    # the launcher started the recorder again, into a second part; the run went on
    assert proc.returncode == 0, stdout
    part = rec.with_suffix(".part1.mcap")
    assert f"recorder exited with signal SIGKILL: starting it again (1/3); the recording " \
           f"goes on in {part}" in stdout
    launched = read_metrics(out / "metrics.csv")
    r1 = load_recording(part)  # the later trials, whole, each as the launcher saw it
    assert len(r1.metrics) >= 10
    np.testing.assert_array_equal(r1.metrics, launched[r1.metrics[:, 0].astype(int)])

    r = load_recording(rec)  # no summary, no footer: read up to the kill
    assert r.report.cut_short and not r.report.damaged  # only the chunk in progress is lost
    k = len(r.metrics)
    assert k >= 3  # trials 0..2 were complete and flushed long before the kill
    np.testing.assert_array_equal(r.metrics, launched[:k])

    fixed = tmp_path / "fixed.mcap"
    assert main(["mcap-repair", str(rec), "-o", str(fixed)]) == 0
    from mcap.reader import make_reader

    with fixed.open("rb") as fh:
        assert make_reader(fh).get_summary().statistics.message_count == r.messages
    np.testing.assert_array_equal(load_recording(fixed).metrics, r.metrics)


def test_simulate_record_analyses_to_the_simulators_metrics(tmp_path):
    rec = tmp_path / "sim.mcap"
    assert main(["simulate", "paper-triangle3", "--trials", "6", "--no-plots", "--out",
                 str(tmp_path / "s"), "--record", str(rec)]) == 0
    ref = simulate(load_scenario("paper-triangle3"), trials=6).metrics
    r = load_recording(rec)
    np.testing.assert_allclose(r.metrics, ref, rtol=1e-13, atol=1e-13)
    # the same topics and schemas as the stack's recorder
    from mcap.reader import make_reader

    with rec.open("rb") as fh:
        s = make_reader(fh).get_summary()
    by_topic = {c.topic: s.schemas[c.schema_id].name for c in s.channels.values()}
    for c in s.channels.values():  # and the type hashes a ROS writer offers
        assert c.metadata["topic_type_hash"] == type_hash(s.schemas[c.schema_id].name)
    assert by_topic["/formation/robot_2/trajectory"] == "nav_msgs/msg/Path"
    assert by_topic["/formation/robot_2/cmd_vel"] == "geometry_msgs/msg/Twist"
    assert r.delays["robot_1->robot_2"]  # the drawn delays, as the robots would count them
    check_file(rec)  # rosbag2's record, as `ros2 bag info` / `play` decode it
    check_frames_and_bag(rec, n=3, samples=3 * 141)  # the kept trials' frames: 0, 1 and 5
    # what the stack's recorder adds: per kept trial (0, 1 and 5 of 6) the desired paths and
    # per pose its desired pose and error, the markers; per trial each robot's largest errors
    assert by_topic["/formation/markers"] == "visualization_msgs/msg/MarkerArray"
    counts = Counter(m.topic for m in read_messages(rec))
    for i in (1, 2, 3):
        assert counts[f"/formation/robot_{i}/desired_path"] == 3
        assert counts[f"/formation/robot_{i}/desired_pose"] == 3 * 141
        assert counts[f"/formation/robot_{i}/tracking_error"] == 3 * 141
        assert counts[f"/formation/robot_{i}/trial_error"] == 6
    assert counts["/formation/markers"] > 3
    from geometry_msgs.msg import Vector3Stamped
    from rclpy.serialization import deserialize_message

    peaks = np.zeros((6, 3, 2))  # trial, robot, (position, heading)
    for m in read_messages(rec):
        if m.topic.endswith("/trial_error"):
            v = deserialize_message(m.data, Vector3Stamped).vector
            peaks[int(v.z), int(m.topic.split("/")[2][6:]) - 1] = (v.x, v.y)
    # the team's largest, every trial (per pose or whole: the same numbers): the metrics
    np.testing.assert_allclose(peaks.max(axis=1), ref[:, 1:3], rtol=1e-12, atol=1e-15)
    assert main(["analyze", str(rec), "--out", str(tmp_path / "an")]) == 0
    assert (tmp_path / "an" / "report.html").exists()


@pytest.mark.ros
@pytest.mark.multiprocess
def test_a_stored_run_file_launched_again_records_into_its_new_folder(ros_env, tmp_path):
    """A recorded run's run.yaml has no null; launched again with --out NEW it records under
    NEW and writes nothing into the old run's folder (its recording's path, given relative
    to the caller's folder, went to OUT/runs/... before)."""
    import yaml

    def run(*args: str) -> subprocess.CompletedProcess[str]:
        argv = [sys.executable, "-m", "formation_ilc.cli", "launch", *args, "--no-plots",
                "--timeout", "20"]
        proc = subprocess.Popen(argv, env=ros_env, cwd=tmp_path, stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True, start_new_session=True)
        try:
            out, _ = proc.communicate(timeout=240)
        finally:
            stop_group(proc)
        return subprocess.CompletedProcess(argv, proc.returncode, out, "")

    first = run("paper-triangle3", "--trials", "1", "--seed", "3", "--out", "runs/a",
                "--record", "runs/a/run.mcap", "--domain-id", ros_env["ROS_DOMAIN_ID"])
    assert first.returncode == 0, first.stdout
    old = tmp_path / "runs" / "a"
    text = (old / "run.yaml").read_text()
    assert "null" not in text and "record: '@run/run.mcap'" in text, text
    assert yaml.safe_load(text)["network"]["domain_id"] == int(ros_env["ROS_DOMAIN_ID"])
    before = {p: p.stat().st_mtime_ns for p in old.rglob("*")}
    again = run("runs/a/run.yaml", "--out", "runs/new")
    assert again.returncode == 0, again.stdout
    assert (tmp_path / "runs" / "new" / "run.mcap").is_file()
    assert {p: p.stat().st_mtime_ns for p in old.rglob("*")} == before
    a = read_metrics(old / "metrics.csv")
    b = read_metrics(tmp_path / "runs" / "new" / "metrics.csv")
    np.testing.assert_allclose(np.array(a)[:, 1:7], np.array(b)[:, 1:7], rtol=0, atol=1e-9)
