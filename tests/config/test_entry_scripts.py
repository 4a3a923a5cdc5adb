"""The node executables are one list (``config.roster.ENTRY_SCRIPTS``): every process a
roster starts and every plant's runs one of them, and the ``ros2 run`` names are derived
from it (``plan.processes.ROS2_RUN``)."""

from dataclasses import replace

import numpy as np
import pytest

from formation_ilc.config.plants import PLANTS, plant
from formation_ilc.config.roster import ENTRY_SCRIPTS, Lineup, roster
from formation_ilc.plan.processes import ROS2_RUN


@pytest.mark.parametrize("name", PLANTS)
def test_every_process_runs_an_entry_script_of_the_list(name):
    row = plant(name)
    assert row.entry is None or row.entry in ENTRY_SCRIPTS
    a = np.ones((3, 3)) - np.eye(3)
    lineup = Lineup(3, plant=name, adjacency=a, leader=np.array([1.0, 0.0, 0.0]),
                    fake_drivers=row.per_robot, physics_bases=row.driver == "base")
    for links in ("emulated", "direct"):
        for lu in (lineup, lineup.for_keystore()):
            r = roster(replace(lu, links=links))
            entries = {m.entry for m in r.members if m.entry is not None}
            assert entries and entries <= set(ENTRY_SCRIPTS), entries - set(ENTRY_SCRIPTS)


def test_the_ros2_run_names_are_the_list_s():
    assert set(ROS2_RUN) == set(ENTRY_SCRIPTS)
    assert ROS2_RUN["formation-ilc-virtual-leader"] == "virtual_leader"
    assert ROS2_RUN["formation-ilc-physics-bases"] == "physics_bases"
    assert len(set(ROS2_RUN.values())) == len(ROS2_RUN)
