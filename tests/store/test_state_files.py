"""State files read without trusting them: bounded, regular files only, every counter
checked, one error naming the file (formation_ilc.store.bounded, robotstate, runfile)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import zipfile

import numpy as np
import pytest

from formation_ilc.config.scenario import load_scenario
from formation_ilc.store.bounded import StateFileError, read_bounded
from formation_ilc.store.memoryfile import MemoryFileError
from formation_ilc.store.robotstate import RobotState, load_state, save_state
from formation_ilc.store.runfile import RunFileError, load_run, require, reroot, save_run

SC = load_scenario("paper-triangle3")


def state(it: int = 2, slot: int = 2, pit: int = 1, pslot: int = 1) -> RobotState:
    m = np.full((SC.samples, 2), 0.25)
    return RobotState(m, it, slot, m * 2, pit, pslot)


def test_a_missing_file_is_none_and_a_small_one_reads(tmp_path):
    assert read_bounded(tmp_path / "none", 10, "x") is None
    (tmp_path / "a").write_bytes(b"0123456789")
    assert read_bounded(tmp_path / "a", 10, "x") == b"0123456789"
    with pytest.raises(StateFileError, match=r"a: 10 bytes, more than x can be \(9 bytes"):
        read_bounded(tmp_path / "a", 9, "x")


def test_a_fifo_is_refused_at_once_and_dev_zero_is_never_read(tmp_path):
    fifo = tmp_path / "leader.json"
    os.mkfifo(fifo)
    # in a child, so that a reader that waits for a writer fails the test, not hangs it
    code = ("import sys; from formation_ilc.store.bounded import read_bounded, StateFileError\n"
            "try: read_bounded(sys.argv[1], 4096, 'a leader state file')\n"
            "except StateFileError as e: print(e)")
    res = subprocess.run([sys.executable, "-c", code, str(fifo)], capture_output=True,
                         text=True, timeout=60)
    assert res.stdout.strip() == f"{fifo}: a FIFO, not a leader state file (a regular file " \
                                 f"is needed)"
    link = tmp_path / "run.json"
    link.symlink_to("/dev/zero")
    with pytest.raises(StateFileError, match="a character device, not a run.json"):
        read_bounded(link, 64 << 10, "a run.json")
    with pytest.raises(StateFileError, match="a folder"):
        read_bounded(tmp_path, 10, "x")


def test_a_robot_state_round_trips(tmp_path):
    path = tmp_path / "robot_1.npz"
    save_state(path, state(), SC, 1)
    st = load_state(path, SC, 1)
    assert (st.iterations, st.slot, st.prev_iterations, st.prev_slot) == (2, 2, 1, 1)
    np.testing.assert_array_equal(st.prev_memory, np.full((SC.samples, 2), 0.5))


@pytest.mark.parametrize("damage", ["truncate", "flip", "zip_of_junk", "empty"])
def test_a_damaged_robot_state_is_one_error_naming_the_file(tmp_path, damage):
    path = tmp_path / "robot_2.npz"
    save_state(path, state(), SC, 2)
    data = bytearray(path.read_bytes())
    if damage == "truncate":
        data = data[: len(data) // 2]
    elif damage == "flip":
        # a bit inside the memory array's bytes: the zip's CRC no longer matches
        at = data.index(np.float64(0.25).tobytes()) + 3
        data[at] ^= 0x10
    elif damage == "zip_of_junk":
        with zipfile.ZipFile(path, "w") as zf:
            zf.writestr("memory.npy", b"junk")
        data = bytearray(path.read_bytes())
    else:
        data = bytearray()
    path.write_bytes(bytes(data))
    with pytest.raises(MemoryFileError) as err:
        load_state(path, SC, 2)
    msg = str(err.value)
    assert msg.startswith(f"{path}: ") and "\n" not in msg
    assert "damaged robot state" in msg or "not a robot state file" in msg


@pytest.mark.parametrize("it, slot, pit, pslot", [(-1, -1, 0, -1), (3, 1, 2, 0),
                                                   (5, 5, 3, 3), (2, 2, 1, 4)])
def test_counters_no_learner_can_write_are_refused(tmp_path, it, slot, pit, pslot):
    path = tmp_path / "robot_1.npz"
    save_state(path, state(it, slot, pit, pslot), SC, 1)
    with pytest.raises(MemoryFileError, match="inconsistent robot state"):
        load_state(path, SC, 1)


def test_a_robot_state_larger_than_its_scenario_allows_is_not_read(tmp_path):
    path = tmp_path / "robot_1.npz"
    path.write_bytes(b"\0" * (2 * 16 * SC.samples + (64 << 10) + 1))
    with pytest.raises(MemoryFileError, match="more than a robot state file can be"):
        load_state(path, SC, 1)
    path.unlink()
    path.symlink_to("/dev/zero")
    with pytest.raises(MemoryFileError, match="a character device"):
        load_state(path, SC, 1)


def test_run_json_paths_into_the_folder_follow_the_folder(tmp_path):
    a = tmp_path / "a"
    a.mkdir()
    save_run(a, {"scenario": str(a / "my.yaml"), "record": a / "run.mcap", "trials": 3,
                 "out": str(a), "run_id": "r1", "init_memory": "/elsewhere/memory.npz"})
    stored = json.loads((a / "run.json").read_text())
    assert stored["record"] == "@run/run.mcap" and stored["scenario"] == "@run/my.yaml"
    assert stored["init_memory"] == "/elsewhere/memory.npz"
    b = tmp_path / "copy"
    b.mkdir()
    (b / "run.json").write_bytes((a / "run.json").read_bytes())
    d = load_run(b)
    assert d["record"] == str(b / "run.mcap") and d["scenario"] == str(b / "my.yaml")
    assert d["out"] == str(b) and d["init_memory"] == "/elsewhere/memory.npz"
    # a run.json written before: absolute paths under its own "out"
    old = {"scenario": "paper-triangle3", "record": "/runs/x/run.mcap", "out": "/runs/x",
           "run_id": "r1"}
    assert reroot(old, b)["record"] == str(b / "run.mcap")
    assert load_run(tmp_path) is None


@pytest.mark.parametrize("text, why", [("[1]", "expected a JSON object"),
                                       ("{", "unreadable: not JSON"),
                                       ('{"scenario": 5, "out": "x", "run_id": "r"}',
                                        "scenario: "),
                                       ('{"scenario": "s", "out": "x", "run_id": "r", '
                                        '"trials": -5}', "trials: -5"),
                                       ('{"scenario": "s", "out": "x", "run_id": "r", '
                                        '"trials": true}', "trials: "),
                                       ('{"out": "x", "run_id": "r"}', "scenario is missing")])
def test_a_bad_run_json_is_one_error_naming_the_field(tmp_path, text, why):
    (tmp_path / "run.json").write_text(text)
    with pytest.raises(RunFileError, match=why) as err:
        require(load_run(tmp_path), tmp_path)
    assert str(err.value).startswith(str(tmp_path / "run.json"))
