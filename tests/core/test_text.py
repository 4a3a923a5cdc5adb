"""Wire text made printable (formation_ilc.core.text) and the run-level checks of a
node's diagnostics (formation_ilc.core.links.check_for_run)."""

from __future__ import annotations

import pytest

from formation_ilc.core.clock import Malformed
from formation_ilc.core.links import check_diagnostics, check_for_run
from formation_ilc.core.text import printable, printable_tree


def test_printable_escapes_every_control_character_and_cuts():
    assert printable("a\x1b[2Kb\r\n\x07\x7f\x9b\u202e") == \
        "a\\x1b[2Kb\\x0d\\x0a\\x07\\x7f\\x9b\\u202e"
    assert printable("ok: é, 30 °C") == "ok: é, 30 °C"
    assert printable("x" * 50, limit=10) == "x" * 10
    tree = printable_tree({"node\x1b": ["\x1b[1A", 3, {"k": "\x00"}], "n": 1.5})
    assert tree == {"node\\x1b": ["\\x1b[1A", 3, {"k": "\\x00"}], "n": 1.5}


def test_a_contact_is_checked_field_by_field():
    good = {"slot": 2, "sample": 5, "line": "robots 1 and 2 touch", "action": "stop",
            "pairs": [[1, 2]], "tilt": None}
    check_diagnostics({"node": "physics_sim", "trial": 2, "contact": good})
    for bad in ({"slot": "boom"}, {"slot": -1}, {"action": "explode"}, {"line": 7},
                {"pairs": "all"}, {"tilt": "high"}, {"sample": 1.5}):
        with pytest.raises(Malformed, match="contact"):
            check_diagnostics({"node": "physics_sim", "trial": 2,
                               "contact": dict(good, **bad)})


def test_a_report_names_a_trial_the_run_has_and_contacts_only_from_its_plant_with_bodies():
    check_for_run({"node": "robot_1", "trial": 9}, 10)
    check_for_run({"node": "robot_1", "trial": -1}, 10)  # not ready yet
    check_for_run({"node": "physics_sim", "trial": 3,
                   "contact_report": {"slot": 3, "pairs": []}}, 10, ("physics_sim",))
    with pytest.raises(Malformed, match="trial 99"):
        check_for_run({"node": "robot_1", "trial": 99}, 10)
    with pytest.raises(Malformed, match="trial -2"):
        check_for_run({"node": "robot_1", "trial": -2}, 10)
    with pytest.raises(Malformed, match=r"contact_report from a node.*\(none\)"):
        check_for_run({"node": "robot_sim", "trial": 3,
                       "contact_report": {"slot": 3, "pairs": [[1, 2]]}}, 10)
    with pytest.raises(Malformed, match=r"contact from a node.*physics_sim"):
        check_for_run({"node": "robot_2", "trial": 3, "contact": {"slot": 3}}, 10,
                      ("physics_sim",))
    # the physics bases watch their bodies too
    check_for_run({"node": "physics_bases", "trial": 3,
                   "contact_report": {"slot": 3, "pairs": []}}, 10,
                  ("physics_bases",))
    with pytest.raises(Malformed, match="filter of slot -1"):
        check_for_run({"node": "robot_2", "trial": 3, "filter": {"slot": -1}}, 10)
