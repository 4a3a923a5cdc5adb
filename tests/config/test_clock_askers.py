"""Who asks the leader's clock is one rule (``config.roster.leader_clock_askers``): the
roster grants the leader exactly those questions, and the leader node answers the same
(``virtual_leader.node``, from the team it waits for)."""

import numpy as np
import pytest

from formation_ilc.config.roster import Lineup, leader_clock_askers, roster
from formation_ilc.core import names as nm


def test_the_robots_that_hear_the_leader_and_the_bridges_ask():
    assert leader_clock_askers(np.array([1.0, 0.0, 0.5]), ["bridge_1", "bridge_2"]) == [
        "robot_1", "robot_3", "bridge_1", "bridge_2"]
    assert leader_clock_askers(np.zeros(2), []) == []


@pytest.mark.parametrize("plant", ["sim", "pioneer", "base"])
def test_the_leader_s_grant_is_the_rule_s(plant):
    a = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=float)
    lead = np.array([1.0, 0.0, 0.0])
    r = roster(Lineup(3, plant=plant, adjacency=a, leader=lead, clocks=True))
    (leader,) = r.by_role("leader")
    pings = sorted(t for t in leader.subscribe if t.endswith("/clock/ping"))
    bridges = [m for m in r.team.expected if m.startswith(nm.BRIDGE_PREFIX)]
    assert bool(bridges) == (plant != "sim")
    want = sorted(nm.clock_ping_topic(x) for x in leader_clock_askers(lead, bridges))
    assert pings == want and want
