"""The kinematic simulator node (robot_sim.node) in-process: hostile input to its handlers
is taken or counted, never a crash."""

from __future__ import annotations

import json

import pytest

pytestmark = pytest.mark.ros

rclpy = pytest.importorskip("rclpy")
from geometry_msgs.msg import Twist  # noqa: E402
from hypothesis import example, given  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

import msgs_schema as ms  # noqa: E402
from tests.hostile import CFG, FUZZ, Outcomes, dropped, events, twists  # noqa: E402


def test_fuzz_simulator_handlers(context):
    from robot_sim.node import SimNode

    sim = SimNode(context=context)
    sim.follow_config(CFG)
    seen = Outcomes()
    try:
        @FUZZ
        @example(msg=ms.u_to_twist((0.2, 0.1)), r=1, state="in_trial")
        @example(msg=ms.u_to_twist((0.2, 0.1)), r=1, state="between")
        @example(msg=ms.json_to_msg({"event": "start", "trial": 1, "seq": 1}), r=0,
                 state="between")
        @example(msg=ms.json_to_msg({"event": "start", "trial": 1, "seq": 1}), r=0,
                 state="not_ready")
        @example(msg=ms.json_to_msg({"event": "start", "trial": 2, "seq": 1}), r=0,
                 state="between")
        @given(msg=st.one_of(events, twists), r=st.integers(0, 2),
               state=st.sampled_from(["between", "in_trial", "not_ready"]))
        def prop(msg, r, state):
            plant, f = sim.plant, sim.plant.follower
            f.slot, f.trial, f.seen = 0, 0, 0
            # "in_trial": ready for the next trial, but inside this one
            plant.in_trial, f.ready = state == "in_trial", state != "not_ready"
            plant.pending = {0, 1, 2} if plant.in_trial else set()
            plant.t = 5
            before = dropped(sim)
            if isinstance(msg, Twist):
                sim._on_cmd(msg, r)
                assert plant.k == 0
                assert dropped(sim) in (before, before + 1)
                if dropped(sim) == before:  # taken: inside a trial, a finite planar command
                    assert state == "in_trial" and r not in plant.pending
                    assert plant.u[r, 5].tolist() == [msg.linear.x, msg.angular.z]
                seen(dropped(sim) == before)
                return
            sim._on_event(msg)
            if plant.k != 0:  # only the start of the next slot, between trials, once ready
                ev = json.loads(msg.data)
                assert (ev["event"], ev["trial"], state) == ("start", 1, "between")
                assert ev["seq"] > 0
                assert dropped(sim) == before
            elif dropped(sim) == before:
                # not counted: end, done, an abort (answered), or the leader's repeat of the
                # start taken (slot 0, seq 0)
                ev = json.loads(msg.data)
                assert ev["event"] in ("end", "done", "abort") or (
                    ev["event"] == "start" and ev.get("slot", ev["trial"]) == 0
                    and ev["seq"] == 0)
            else:
                assert dropped(sim) == before + 1
            seen(plant.k != 0)
        prop()
        seen.check()
    finally:
        sim.destroy_node()
