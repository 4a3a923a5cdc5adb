"""The planner from a ``LaunchOptions`` value, with no parser (``plan.build.build_plan``):
what runs, what is refused (``build_plan``: ``decide`` on this machine, then ``prepare``;
test_decide.py has what each of the two does)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from formation_ilc.plan.build import build_plan
from formation_ilc.plan.options import LaunchOptions
from formation_ilc.plan.specs import NoRun

HERE = Path(__file__).parent


def opts(tmp_path: Path, **kw) -> LaunchOptions:
    return LaunchOptions(**{"scenario": "paper-triangle3", "out": tmp_path / "run",
                            "domain_id": 42, **kw})


def test_a_simulated_run_plans_one_process_per_node(tmp_path):
    plan = build_plan(opts(tmp_path, trials=5, seed=3))
    assert [s.name for s in plan.nodes] == ["virtual_leader", "robot_sim", "link_emulator",
                                            "robot_1", "robot_2", "robot_3"]
    assert plan.domain == 42 and plan.config.mode == "lockstep"
    assert plan.config.links == "emulated" and plan.config.scenario.trials == 5
    assert plan.config.run_id.startswith("r")


def test_the_given_run_id_is_the_run_s(tmp_path):
    assert build_plan(opts(tmp_path, run_id="rmine")).config.run_id == "rmine"


def test_bridges_run_on_the_wall_clock_with_direct_links(tmp_path):
    plan = build_plan(opts(tmp_path, plant="pioneer", fake_drivers=True, allow_contact=True))
    assert plan.config.mode == "wallclock" and plan.config.links == "direct"
    assert [s.name for s in plan.nodes if s.name.startswith("bridge_")] == [
        "bridge_1", "bridge_2", "bridge_3"]


@pytest.mark.parametrize(("kw", "start"), [
    ({"scenario": None}, "a SCENARIO is required"),
    ({"max_restarts": -1}, "--max-restarts must be >= 0"),
    ({"plant": "pioneer", "mode": "lockstep"}, "--plant pioneer runs --mode wallclock"),
    ({"namespace": "team2"}, "--namespace 'team2': an absolute ROS namespace"),
])
def test_what_no_run_can_have_is_refused_in_one_line(tmp_path, kw, start):
    with pytest.raises(NoRun) as info:
        build_plan(opts(tmp_path, **kw))
    assert info.value.message.startswith(start) and "\n" not in info.value.message


def test_no_test_here_reaches_the_parser():
    """tests/plan/ plans from LaunchOptions: none of its modules imports the command line
    (``formation_ilc.cli``, argparse) or names its parser."""
    for path in sorted(HERE.glob("*.py")):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.Import | ast.ImportFrom):
                names = [a.name for a in node.names] if isinstance(node, ast.Import) else [
                    node.module or ""]
                assert not any(n == "argparse" or n.startswith("formation_ilc.cli")
                               for n in names), (path.name, names)
            if isinstance(node, ast.Name | ast.Attribute):
                name = node.id if isinstance(node, ast.Name) else node.attr
                assert name not in ("build_parser", "launch_parser"), path.name
