"""The view's CDR shortcuts (msgs_schema: world_pose_cdr, stamped_cdr, vector_cdr) agree
with rclpy's own (de)serialization, and refuse what world_pose refuses."""

from __future__ import annotations

import math

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped, Vector3Stamped
from rclpy.serialization import deserialize_message, serialize_message

import msgs_schema as ms


@pytest.mark.parametrize("frame", ["map"])
@pytest.mark.parametrize("stamp", [0, 1, 1_999_999_999, 123 * 10**9 + 456])
@pytest.mark.parametrize("eta", [(1.0, -2.5, 0.3), (0.0, 0.0, -3.0), (1e6, 3e-9, math.pi)])
def test_pose_and_vector_cdr_round_trip(frame, stamp, eta):
    data = serialize_message(ms.pose_to_msg(eta, stamp, frame))
    got, ns = ms.world_pose_cdr(data)
    want, wns = ms.world_pose(deserialize_message(data, PoseStamped))
    assert ns == wns == stamp
    np.testing.assert_array_equal(got, want)
    tpl = serialize_message(ms.pose_to_msg(eta, 0, frame))
    assert ms.stamped_cdr(tpl, stamp) == data
    v = ms.vector_cdr(serialize_message(ms.vector_msg(0, 0.0, 0.0)), stamp, *eta)
    assert v == serialize_message(ms.vector_msg(stamp, *eta))
    m = deserialize_message(v, Vector3Stamped)
    assert (m.vector.x, m.vector.y, m.vector.z) == eta


def test_pose_cdr_refuses_what_world_pose_refuses():
    ok = ms.pose_to_msg((1.0, 2.0, 0.5), 10, "map")
    with pytest.raises(ms.MalformedMessage):
        ms.world_pose_cdr(serialize_message(ms.pose_to_msg((1.0, 2.0, 0.5), 10, "odom")))
    bad = ms.pose_to_msg((1.0, 2.0, 0.5), 10, "map")
    bad.pose.orientation.x = 0.5
    with pytest.raises(ms.MalformedMessage):
        ms.world_pose_cdr(serialize_message(bad))
    bad = ms.pose_to_msg((float("nan"), 2.0, 0.5), 10, "map")
    with pytest.raises(ms.MalformedMessage):
        ms.world_pose_cdr(serialize_message(bad))
    with pytest.raises(ms.MalformedMessage):
        ms.world_pose_cdr(serialize_message(ok)[:40])


@pytest.mark.parametrize("scenario", ["paper-triangle3", "paper-hexagon6"])
def test_the_markers_template_writes_what_markers_msg_serializes(scenario):
    from visualization_msgs.msg import MarkerArray

    from formation_ilc.config.scenario import load_scenario
    from formation_ilc.protocol.view import graph_links, outline_order

    sc = load_scenario(scenario)
    eta_d = sc.desired.eta
    outline, links = outline_order(eta_d[:, 0]), graph_links(sc.graph.in_links()[0])
    footprint = (0.455, 0.381, -0.045)  # a Pioneer 3-DX's, about its axle
    tpl = ms.MarkersTemplate(sc.n, outline, links, footprint)
    rng = np.random.default_rng(3)
    for _ in range(10):
        s = int(rng.integers(0, sc.samples + 1))
        stamp = int(rng.integers(0, 2**31 * 10**9))
        pos = {r: tuple(rng.normal(scale=3.0, size=2)) for r in range(sc.n)}
        ours = tpl.cdr(stamp, eta_d[:, s, :2], pos)
        theirs = serialize_message(ms.markers_msg(stamp, eta_d[:, s, :2], outline, links, pos,
                                                  footprint))
        assert len(ours) == len(theirs)  # (rclpy leaves padding bytes uninitialised)
        assert deserialize_message(ours, MarkerArray) == deserialize_message(theirs,
                                                                              MarkerArray)
    # per robot its footprint and heading, in its own frame (they move with /tf)
    got = deserialize_message(ours, MarkerArray).markers
    for kind in ("footprint", "heading"):
        mine = [m for m in got if m.ns == kind]
        assert [m.header.frame_id for m in mine] == [f"robot_{r + 1}/base_link"
                                                     for r in range(sc.n)]
        assert all(m.frame_locked for m in mine)
    fp = next(m for m in got if m.ns == "footprint")
    xs, ys = [p.x for p in fp.points], [p.y for p in fp.points]
    assert (max(xs) - min(xs), max(ys) - min(ys)) == pytest.approx((0.455, 0.381))


def test_the_observer_publishes_a_starts_desired_paths_once():
    """The leader repeats a start while its slot does not move: the view's desired paths go
    out at the start, not again at each repeat; a later slot's start sends them again."""
    from formation_ilc.config.runconfig import make_config
    from formation_ilc.nodes.observer import Observer
    from formation_ilc.protocol.schedule import TrialEvent

    cfg = make_config("paper-triangle3", seed=1)
    sent: list[str] = []
    obs = Observer(None, cfg, lambda topic, data, ns: sent.append(topic))
    paths = {ms.desired_path_topic(r + 1) for r in range(cfg.scenario.n)}
    start = TrialEvent("start", 0, 0, 0)
    obs.on_event(start)
    assert set(sent) == paths and len(sent) == len(paths)
    obs.on_event(start)
    obs.on_event(start)
    assert len(sent) == len(paths)
    obs.on_event(TrialEvent("abort", 0, 0, 1))
    obs.on_event(TrialEvent("start", 0, 1, 2))
    assert len(sent) == 2 * len(paths)
