"""The writers a node accepts, by topic (formation_ilc.protocol.writers)."""

from __future__ import annotations

from formation_ilc.protocol.writers import (
    HOLD,
    OK,
    PIN_HOLD,
    REFRESH,
    UNKNOWN,
    UNKNOWN_NODE,
    WriterTable,
    enclave_prefix,
    forged_line,
    participant,
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


def gid(part: int, entity: int = 1) -> bytes:
    """A writer's GID: 12 bytes of its participant, 4 of its entity (Fast DDS's GUID)."""
    return bytes([part]) * 12 + entity.to_bytes(4, "big")


R1, R1B, IMP, NEW, MON = gid(1), gid(1, 2), gid(9), gid(7), gid(4)
IMPOSTOR = "/formation/robot_1 (second participant)"


def pinned() -> WriterTable:
    """robot_1 (participant 1) has said ready; a second participant named robot_1 (9)
    is listed beside it, and the launcher's monitor (4)."""
    t = WriterTable(NS)
    t.learn(READY, [(R1, "robot_1", NS), (MON, "monitor", NS)])
    assert t.claims(READY, R1, "robot_1") == OK
    t.learn(READY, [(R1, "robot_1", NS), (MON, "monitor", NS), (IMP, "robot_1", NS),
                    (R1B, "robot_1", NS)])
    return t


def test_a_participant_is_its_gids_first_twelve_bytes():
    assert participant(R1) == participant(R1B) != participant(IMP)


def test_a_second_participant_under_a_held_name_is_an_impostor_once_the_holder_speaks():
    t = pinned()
    # held while the holder is listed: it may be a killed holder's successor
    assert t.judge(READY, IMP) == UNKNOWN and t.hold_for(READY, IMP) == PIN_HOLD
    assert t.hold_for(READY, R1) == HOLD
    assert t.judge(READY, R1B) == OK  # another writer of the holder's participant
    assert t.claims(READY, R1, "robot_1") == OK  # the holder lives
    why = t.judge(READY, IMP)
    assert "second participant named /formation/robot_1" in why and "spoke" in why
    # from now on at once, in its own name or not, and after the holder left
    assert t.claims(READY, IMP, "robot_1") != OK
    t.learn(READY, [(IMP, "robot_1", NS)])
    assert t.judge(READY, IMP) != OK
    assert t.report() == {READY: {IMPOSTOR: 3}}


def test_a_silent_holder_still_listed_after_pin_hold_makes_the_second_an_impostor():
    t = pinned()
    assert t.judge(READY, IMP) == UNKNOWN
    assert "still listed" in t.judge(READY, IMP, patient=True)
    assert t.forged[(READY, IMPOSTOR)] == 1


def test_the_name_passes_to_the_next_participant_when_its_holder_left_the_graph():
    """A killed robot's participant stays listed until its lease runs out; its restarted
    successor's messages wait until then, and are taken."""
    t = pinned()
    t.learn(READY, [(R1, "robot_1", NS), (NEW, "robot_1", NS)])
    assert t.judge(READY, NEW) == UNKNOWN  # the predecessor is still listed
    t.learn(READY, [(NEW, "robot_1", NS)])  # its lease ran out
    assert t.claims(READY, NEW, "robot_1") == OK
    assert t.holders[(READY, "/formation/robot_1")] == participant(NEW)
    assert t.total == 0


def test_the_monitors_down_frees_the_name_at_once():
    t = pinned()
    t.learn(READY, [(R1, "robot_1", NS), (MON, "monitor", NS), (NEW, "robot_1", NS)])
    assert t.judge(READY, NEW) == UNKNOWN
    assert t.claims(READY, MON, "robot_1", down=True) == OK  # the launcher restarts it
    assert t.claims(READY, NEW, "robot_1") == OK  # its predecessor still listed
    # the predecessor's last words, still in the reader's queue, are taken but hold nothing
    assert t.claims(READY, R1, "robot_1") == OK
    assert t.holders[(READY, "/formation/robot_1")] == participant(NEW)
    # a down from anyone else frees nothing
    assert t.claims(READY, NEW, "robot_1", down=True) == OK
    t.learn(READY, [(NEW, "robot_1", NS), (MON, "monitor", NS), (IMP, "robot_1", NS)])
    assert t.claims(READY, IMP, "robot_2", down=True) != OK
    assert t.holders[(READY, "/formation/robot_1")] == participant(NEW)


def test_a_killed_holders_late_message_does_not_take_its_name_back():
    """The launcher's down can be taken before the last report of the node it restarts:
    that report must not pin the name to a dead participant, whose successor would then
    be held until the lease of the dead one runs out."""
    t = pinned()
    t.learn(READY, [(R1, "robot_1", NS), (MON, "monitor", NS), (NEW, "robot_1", NS)])
    assert t.claims(READY, MON, "robot_1", down=True) == OK
    assert t.claims(READY, R1, "robot_1") == OK  # late, after the down
    assert t.claims(READY, NEW, "robot_1") == OK  # at once, not held
    assert t.total == 0


def test_a_down_heard_again_does_not_free_the_successors_name():
    """The down is latched: a reader that matches its writer anew hears it again. The
    successor that took the name keeps it; a down of its own process frees it."""
    t = pinned()
    t.learn(READY, [(R1, "robot_1", NS), (MON, "monitor", NS), (NEW, "robot_1", NS),
                    (IMP, "robot_1", NS)])
    assert t.claims(READY, MON, "robot_1", down=True, boot="101") == OK
    assert t.claims(READY, NEW, "robot_1") == OK
    assert t.claims(READY, MON, "robot_1", down=True, boot="101") == OK  # heard again
    assert t.holders[(READY, "/formation/robot_1")] == participant(NEW)
    assert t.judge(READY, IMP) == UNKNOWN  # held: the name is NEW's
    assert t.claims(READY, MON, "robot_1", down=True, boot="202") == OK  # NEW died
    assert (READY, "/formation/robot_1") not in t.holders


def test_an_impostor_stays_one_when_the_holder_restarts():
    t = pinned()
    t.judge(READY, IMP)
    t.claims(READY, R1, "robot_1")
    assert t.judge(READY, IMP) != OK
    t.learn(READY, [(IMP, "robot_1", NS), (NEW, "robot_1", NS)])  # the holder left
    assert t.judge(READY, IMP) != OK
    assert t.claims(READY, NEW, "robot_1") == OK


def test_a_holder_listed_without_its_name_is_still_there():
    """The graph may list a participant's endpoints without its node's name (before its
    ros_discovery_info, or after a lease drop): its pin holds."""
    t = WriterTable(NS)
    t.learn(READY, [(R1, UNKNOWN_NODE, NS)])
    assert t.judge(READY, R1) == UNKNOWN
    t.learn(READY, [(R1, "robot_1", NS)])
    assert t.claims(READY, R1, "robot_1") == OK  # first seen once named: it holds
    t.learn(READY, [(R1B, UNKNOWN_NODE, NS), (IMP, "robot_1", NS)])
    assert t.judge(READY, IMP) == UNKNOWN
    assert t.judge(READY, IMP, patient=True) != OK


def test_each_topic_pins_on_its_own_and_owned_topics_are_judged_by_name():
    t = pinned()
    diag = "/formation/diagnostics"
    t.learn(diag, [(IMP, "robot_1", NS)])  # the impostor came first on this topic
    assert t.claims(diag, IMP, "robot_1") == OK
    t.own(POSES, "physics_sim")
    t.learn(POSES, [(R1, "physics_sim", NS), (IMP, "physics_sim", NS)])
    assert t.judge(POSES, R1) == OK and t.judge(POSES, IMP) == OK


def secure_gid(enclave: str, rest: int, entity: int = 1) -> bytes:
    """A writer's GID under DDS-Security: its participant's first 6 bytes from the
    certificate subject of ``enclave`` (here a stand-in DER), the other 6 ``rest``."""
    return (enclave_prefix(f"CN={enclave}".encode()) + bytes([rest]) * 6
            + entity.to_bytes(4, "big"))


def test_an_enclave_prefix_is_a_one_bit_and_47_bits_of_the_subjects_sha256():
    import hashlib

    der = b"0\x1d1\x1b0\x19\x06\x03U\x04\x03\x0c\x12/formation/robot_1"
    md = hashlib.sha256(der).digest()
    bits = int.from_bytes(md[:6], "big") >> 1  # the first 47 bits
    assert enclave_prefix(der) == ((1 << 47) | bits).to_bytes(6, "big")
    assert enclave_prefix(der)[0] & 0x80


def test_under_secure_a_name_is_its_enclaves_from_the_first_message():
    """No first-writer window: an insider in robot 3's enclave that names its node
    robot_1 is refused at once, even before robot_1 ever spoke; robot_1's participant,
    and a restarted robot_1 (a new participant of the same enclave), at once too."""
    t = WriterTable(NS, enclaves={f"{NS}/robot_{i}": enclave_prefix(f"CN={NS}/robot_{i}"
                                                                     .encode())
                                  for i in (1, 2, 3)})
    insider, real, restarted = (secure_gid(f"{NS}/robot_3", 5), secure_gid(f"{NS}/robot_1", 6),
                                secure_gid(f"{NS}/robot_1", 7))
    t.learn(READY, [(insider, "robot_1", NS), (real, "robot_1", NS),
                    (restarted, "robot_1", NS)])
    why = t.claims(READY, insider, "robot_1")
    assert "not authenticated in its enclave" in why
    assert t.claims(READY, real, "robot_1") == OK
    assert t.claims(READY, restarted, "robot_1") == OK  # no lease to wait out
    assert t.claims(READY, real, "robot_1") == OK  # and both stay the node's
    assert t.report() == {READY: {IMPOSTOR: 1}}
    # a name without an enclave in the keystore keeps the first participant's pin
    t.learn(READY, [(gid(2), "recorder", NS), (gid(3), "recorder", NS)])
    assert t.claims(READY, gid(2), "recorder") == OK
    assert t.judge(READY, gid(3)) == UNKNOWN
