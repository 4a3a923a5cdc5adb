"""The writers a node accepts, by topic (formation_ilc.protocol.writers)."""

from __future__ import annotations

from formation_ilc.protocol.writers import (
    HOLD,
    OK,
    REFRESH,
    UNKNOWN,
    UNKNOWN_NODE,
    WriterTable,
    forged_line,
    plant_writers,
)

NS = "/formation"
READY, POSES = "/formation/ready", "/formation/team/poses"
G1, G2, G3, G4 = (bytes([i]) * 16 for i in range(1, 5))


def table() -> WriterTable:
    t = WriterTable(NS)
    t.own(POSES, "physics_sim")
    t.learn(POSES, [(G1, "physics_sim", NS), (G2, "forger", "/forger"),
                    (G3, "robot_3", NS), (G4, UNKNOWN_NODE, NS)])
    t.learn(READY, [(G1, "robot_1", NS), (G2, "forger", "/forger"), (G3, "robot_3", NS),
                    (G4, "monitor", NS)])
    return t


def test_an_owned_topic_is_taken_from_its_owner_only():
    t = table()
    assert t.judge(POSES, G1) == OK
    assert "outside the formation's namespace" in t.judge(POSES, G2)
    assert "only physics_sim write it" in t.judge(POSES, G3)
    # the graph lists it, but not its node's name yet: held, then asked again
    assert t.judge(POSES, G4) == UNKNOWN and t.judge(POSES, b"\0" * 16) == UNKNOWN
    assert t.report() == {POSES: {"/forger/forger": 1, "/formation/robot_3": 1}}
    t.learn(POSES, [(G4, "robot_sim", NS)])
    assert t.judge(POSES, G4) != OK and t.total == 3


def test_a_shared_topic_is_taken_in_its_writers_own_name_only():
    t = table()
    assert t.claims(READY, G1, "robot_1") == OK
    assert "in the name of 'robot_1' from /formation/robot_3" in t.claims(READY, G3, "robot_1")
    # only the launcher's monitor says that another node is down
    assert t.claims(READY, G4, "recorder", down=True) == OK
    assert t.claims(READY, G3, "recorder", down=True) != OK
    assert t.claims(READY, G2, "robot_1") != OK  # outside the namespace
    assert t.report() == {READY: {"/forger/forger": 1, "/formation/robot_3": 2}}
    assert t.expire(READY).endswith(f"within {HOLD:g} s") and t.forged[(READY, "?")] == 1


def test_the_graph_is_asked_at_most_every_refresh_period_a_topic():
    t = WriterTable(NS)
    assert t.due(READY, 10.0) and not t.due(READY, 10.0 + REFRESH / 2)
    assert t.due(POSES, 10.0) and t.due(READY, 10.0 + REFRESH)


def test_the_console_line_sums_every_nodes_counts():
    assert forged_line({"a": {}, "b": None}) == ""  # type: ignore[dict-item]
    line = forged_line({"virtual_leader": {READY: {"/forger/forger": 2}},
                        "monitor": {READY: {"/forger/forger": 1}, POSES: {"?": 4}}})
    assert line.startswith("forged: 7 messages refused")
    assert "4 on /formation/team/poses from ?" in line
    assert "3 on /formation/ready from /forger/forger" in line


def test_the_plants_of_one_node_own_the_team_poses():
    assert plant_writers() == {"robot_sim", "physics_sim"}


def test_a_writer_the_graph_never_names_passes_only_for_a_node_no_named_writer_is():
    """The graph loses a participant's node names for good when it is dropped on its
    lease and found again: after HOLD its writer passes for a member that has no named
    writer, never beside one that has."""
    t = WriterTable(NS)
    t.own(POSES, "physics_sim")
    t.learn(READY, [(G1, "robot_1", NS), (G4, UNKNOWN_NODE, NS)])
    t.learn(POSES, [(G4, UNKNOWN_NODE, NS)])
    assert t.judge(READY, G4) == UNKNOWN and t.judge(POSES, G4) == UNKNOWN
    assert t.judge(POSES, G4, patient=True) == OK  # no named physics_sim: it may be it
    assert t.judge(READY, G4, patient=True) == OK
    assert t.claims(READY, G4, "robot_2") == OK
    assert "does not name" in t.claims(READY, G4, "robot_1")  # robot_1 is named: not it
    assert t.judge(READY, b"\0" * 16, patient=True) == UNKNOWN  # never listed at all
    t.learn(POSES, [(G1, "physics_sim", NS)])
    assert t.judge(POSES, G4, patient=True) != OK
    assert t.report() == {POSES: {"(unnamed)": 1}, READY: {"(unnamed)": 1}}
