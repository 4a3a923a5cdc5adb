"""`formation-ilc team N` (formation_ilc/config/generate.py): a pattern and a graph rule to
a scenario that loads, whose graph is the paper's leader-relay tree at any size (condition
(20) holds), and the built-in team50 is what the command writes."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from formation_ilc.cli.commands import main
from formation_ilc.config.generate import positions, relay_tree, team_yaml
from formation_ilc.config.scenario import load_scenario, scenario_from_text
from formation_ilc.model.checks import condition20

SIZES = [1, 2, 3, 4, 5, 6, 7, 11, 24, 50, 100]


@pytest.mark.parametrize("pattern", ["grid", "ring"])
def test_the_pattern_keeps_robots_apart_and_its_path_steps_one_spacing(pattern):
    for n in SIZES:
        pos = np.array(positions(pattern, n, 1.5))
        assert pos.shape == (n, 2)
        if n > 1:
            gaps = [math.dist(a, b) for a, b in itertools.combinations(pos, 2)]
            assert min(gaps) >= 1.5 - 1e-9
        steps = [math.dist(a, b) for a, b in zip(pos, pos[1:], strict=False)]
        assert all(s <= 1.5 + 1e-9 for s in steps), steps  # next on the path: a neighbour


def test_the_relay_tree_is_one_hop_deep_and_relays_to_at_most_two():
    for n in SIZES:
        roots, edges = relay_tree(n)
        followers = [b for _, b in edges]
        assert sorted(roots + followers) == list(range(1, n + 1))  # each robot once
        assert all(a in roots for a, _ in edges)  # a follower follows a robot of the leader
        assert max((followers.count(b) for b in followers), default=1) == 1
        assert max(([a for a, _ in edges].count(r) for r in roots), default=0) <= 2
        assert len(roots) == math.ceil(n / 3)


def test_six_is_the_papers_hexagon_graph_turned_by_one():
    roots, edges = relay_tree(6)
    assert roots == [2, 5] and edges == [(2, 1), (2, 3), (5, 4), (5, 6)]
    hexagon = load_scenario("paper-hexagon6")  # leader sees 1 and 4; 1 -> 2, 6; 4 -> 3, 5
    assert sorted(np.flatnonzero(hexagon.graph.leader) + 1) == [1, 4]


@pytest.mark.parametrize("n, pattern", [(50, "grid"), (100, "grid"), (24, "ring")])
def test_a_generated_team_loads_with_a_spanning_tree_and_condition_20(n, pattern):
    sc = scenario_from_text(team_yaml(n, pattern=pattern), "team.yaml")
    assert sc.n == n and sc.name == f"team{n}"
    sc.graph.check_spanning_tree()
    assert condition20(sc.graph, np.asarray(sc.law.gain), sc.dt) < 1.0
    base = load_scenario("paper-hexagon6")  # the rest is the base scenario's
    assert (sc.dt, sc.samples, sc.uncertainty) == (base.dt, base.samples, base.uncertainty)
    assert (sc.law.kind, sc.law.memory, sc.law.gain_heading) == (
        base.law.kind, base.law.memory, base.law.gain_heading)
    assert set(sc.law.gain) == set(base.law.gain) and set(sc.law.gain_prime) == set(
        base.law.gain_prime)
    offsets = np.asarray(sc.offsets)
    assert np.allclose(offsets, positions(pattern, n, 1.5))


def test_the_built_in_team50_is_what_the_command_writes(tmp_path, capsys):
    assert main(["team", "50", "-o", str(tmp_path / "t.yaml")]) == 0
    assert "wrote" in capsys.readouterr().out
    written = (tmp_path / "t.yaml").read_text()
    builtin = load_scenario("team50")
    assert written == team_yaml(50) == builtin.text
    assert builtin.n == 50


def test_refusals_are_one_line_with_status_2(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["team", "0"])
    assert exc.value.code == 2
    assert "argument N" in capsys.readouterr().err
    assert main(["team", "5", "--from", "no-such-base", "-o", str(tmp_path / "x.yaml")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: no-such-base:") and len(err.splitlines()) == 1
    assert not (tmp_path / "x.yaml").exists()
