"""``launch --resume DIR`` decides from the run's files before anything changes: state files
that are damaged, impossible or disagree are one line naming the file and status 2, with
metrics.csv untouched and no node started; a copied run folder resumes into itself
(formation_ilc.cli.launch, protocol.resume, store.runfile)."""

from __future__ import annotations

import json
import resource
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from formation_ilc.cli.runfile import plan_of
from formation_ilc.config.scenario import load_scenario
from formation_ilc.store.robotstate import RobotState, save_state, state_path
from formation_ilc.store.runfile import save_run

TRIALS = 7
SC = load_scenario("paper-triangle3").with_options(trials=TRIALS)
METRICS = ("trial,max_position_error,max_heading_error,true_max_position_error,"
           "true_max_heading_error,rms_position_error,max_formation_error\n"
           + "".join(f"{k},1,1,1,1,1,1\n" for k in range(3)))


def run_folder(tmp_path: Path, committed: int = 3, robots: int = 3,
               record: bool = False) -> Path:
    """The folder of a run of TRIALS trials interrupted after ``committed`` (every robot at
    ``robots`` learned trials)."""
    out = tmp_path / "run"
    (out / "state").mkdir(parents=True)
    save_run(out, {"scenario": "paper-triangle3", "trials": TRIALS, "seed": None,
                   "out": str(out), "run_id": "rtest", "record":
                   str(out / "run.mcap") if record else None})
    (out / "state" / "leader.json").write_text(json.dumps(
        {"committed": committed, "slot": committed - 1, "seq": committed, "open": False}))
    m = np.zeros((SC.samples, 2))
    for i in range(1, 4):
        save_state(state_path(out / "state", i), RobotState(m, robots, robots - 1, m,
                                                             robots - 1, robots - 2), SC, i)
    (out / "metrics.csv").write_text(METRICS)
    return out


def resume(out: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "formation_ilc.cli", "launch", "--resume",
                           str(out), "--no-plots"], capture_output=True, text=True,
                          timeout=180)


def test_leader_state_saying_999_of_7_trials_done_is_refused_not_reported_done(tmp_path):
    out = run_folder(tmp_path)
    (out / "state" / "leader.json").write_text(json.dumps(
        {"committed": 999, "slot": 999, "seq": 999, "open": False}))
    res = resume(out)
    assert res.returncode == 2, res.stdout + res.stderr
    assert res.stderr == (f"error: --resume: {out}/state/leader.json: impossible schedule "
                          f"state: committed 999 is not in 0..{TRIALS} (the run has {TRIALS} "
                          f"trials)\n")
    assert "done" not in res.stdout
    assert (out / "metrics.csv").read_text() == METRICS


def test_leader_state_below_the_robots_is_refused_and_no_metrics_row_deleted(tmp_path):
    out = run_folder(tmp_path, committed=1, robots=3)
    res = resume(out)
    assert res.returncode == 2, res.stdout + res.stderr
    err = res.stderr.splitlines()
    assert len(err) == 1 and "robot_1.npz: 3 trials learned" in err[0] \
        and "the files disagree" in err[0], res.stderr
    assert (out / "metrics.csv").read_text() == METRICS
    assert not (out / "logs").exists()  # no node was started


@pytest.mark.parametrize("damage", ["truncate", "dev_zero"])
def test_a_damaged_robot_state_is_one_line_naming_it(tmp_path, damage):
    out = run_folder(tmp_path)
    path = state_path(out / "state", 2)
    if damage == "truncate":
        path.write_bytes(path.read_bytes()[:300])
    else:
        path.unlink()
        path.symlink_to("/dev/zero")
    res = resume(out)
    assert res.returncode == 2, res.stdout + res.stderr
    err = res.stderr.splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: --resume: {path}: ") \
        and "Traceback" not in res.stderr, res.stderr
    assert (out / "metrics.csv").read_text() == METRICS


@pytest.mark.parametrize("name", ["leader.json", "run.json"])
def test_a_state_file_linked_to_dev_zero_is_never_read_whole(tmp_path, name):
    out = run_folder(tmp_path)
    path = out / "state" / name if name == "leader.json" else out / name
    path.unlink()
    path.symlink_to("/dev/zero")
    res = resume(out)
    assert res.returncode == 2, res.stdout + res.stderr
    assert f"{path}: a character device" in res.stderr and len(res.stderr.splitlines()) == 1
    peak_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    assert peak_mb < 1024, f"a child peaked at {peak_mb:.0f} MB"


def test_a_copied_run_folder_resumes_into_itself(tmp_path):
    """run.json keeps the recording's path relative to its folder: a copy of the folder
    records (and keeps its state) in the copy, never in the original."""
    import shutil

    from formation_ilc.cli.commands import build_parser

    out = run_folder(tmp_path, record=True)
    (out / "run.mcap").write_bytes(b"x")
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    plan = plan_of(build_parser().parse_args(["launch", "--resume", str(copy)]))
    assert plan.out == copy.resolve() and plan.resumed_at == 3
    assert plan.record == (copy / "run.resumed1.mcap").resolve()
    assert plan.record_root == (copy / "run.mcap").resolve()
    assert all(str(out) not in " ".join(spec.command) for spec in plan.nodes)
    # a run whose first recording was never written records into it on resume
    (copy / "run.mcap").unlink()
    plan = plan_of(build_parser().parse_args(["launch", "--resume", str(copy)]))
    assert plan.record == (copy / "run.mcap").resolve()


def test_a_new_launch_into_a_used_folder_is_refused_and_changes_nothing(tmp_path):
    """A launch (not --resume) into a folder that holds another run: one line naming
    --resume and a fresh folder, status 2, before anything starts; every file of the
    other run as it was (before, the leader went on from its state with the new seed
    and metrics.csv lost its rows)."""
    out = run_folder(tmp_path)
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    res = subprocess.run([sys.executable, "-m", "formation_ilc.cli", "launch",
                          "paper-triangle3", "--trials", "4", "--seed", "7", "--out",
                          str(out), "--no-plots"], capture_output=True, text=True, timeout=180)
    assert res.returncode == 2, res.stdout + res.stderr
    lines = res.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: --out {out}: holds another run "
                                                   f"(run.json, state/, metrics.csv)"), lines
    assert f"--resume {out}" in lines[0] and "fresh folder" in lines[0]
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    assert not (out / "logs").exists()  # nothing started


def test_a_member_host_comes_into_its_ground_stations_used_folder(tmp_path):
    """One run, one folder is the ground station's rule: a member host's launcher (``launch
    RUN.yaml --host r2``, started again after it died) plans into the run's folder, which
    the ground station's files fill, and keeps its own in OUT/hosts/r2; the ground
    station's launcher into the same folder is refused."""
    from formation_ilc.cli.commands import build_parser, main
    from formation_ilc.plan.specs import NoRun

    path = tmp_path / "run.yaml"
    assert main(["run-file", "paper-triangle3", "--host-per-robot", "--domain-id", "7", "-o",
                 str(path)]) == 0
    out = run_folder(tmp_path)
    argv = ["launch", str(path), "--out", str(out), "--no-plots"]
    plan = plan_of(build_parser().parse_args([*argv, "--host", "r2"]))
    assert plan.out == (out / "hosts" / "r2").resolve() and not plan.ground
    with pytest.raises(NoRun, match="holds another run"):
        plan_of(build_parser().parse_args([*argv, "--host", "ground"]))
