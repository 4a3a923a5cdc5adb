import csv
import json
import subprocess
import sys

import pytest

from formation_ilc.cli import main

NO_TREE = """\
name: broken
dt: 0.1
samples: 20
robots: 3
reference: {kind: lemniscate}
formation:
  frame: world
  offsets: {1: {x: 1, y: 0}, 2: {x: -1, y: 0}, 3: {x: 0, y: 1}}
graph:
  leader: {1: 1.0}
  edges: [{from: 3, to: 2}, {from: 2, to: 3}]
"""


def test_simulate_writes_metrics_summary_and_plots(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["simulate", "paper-triangle3", "--trials", "12", "--no-noise", "--no-delay",
                 "--out", str(out)]) == 0
    rows = list(csv.DictReader((out / "metrics.csv").open()))
    assert len(rows) == 12 and rows[0]["trial"] == "0"
    assert {"trial", "max_position_error", "max_heading_error"} <= set(rows[0])
    assert float(rows[-1]["max_position_error"]) < float(rows[0]["max_position_error"])
    summary = json.loads((out / "summary.json").read_text())
    assert summary["trials"] == 12 and summary["law"] == 9 and summary["noise"] is False
    assert (out / "errors.png").stat().st_size > 10_000
    assert (out / "trajectories.png").stat().st_size > 10_000
    assert "max position error" in capsys.readouterr().out


def test_compare_runs_all_laws(tmp_path, capsys):
    assert main(["compare", "paper-triangle3", "--trials", "5", "--out", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    for label in ("(9) feedforward", "(9) literal", "(22) feedforward", "(23) literal"):
        assert label in text
    assert (tmp_path / "compare.png").exists()


def test_check_refuses_graph_without_spanning_tree(tmp_path, capsys):
    p = tmp_path / "broken.yaml"
    p.write_text(NO_TREE)
    assert main(["check", str(p)]) == 2
    cap = capsys.readouterr()
    assert "leader cannot reach robot(s) 2, 3" in cap.out
    assert main(["simulate", str(p), "--out", str(tmp_path / "o")]) == 2
    assert "no spanning tree" in capsys.readouterr().err


def test_check_reports_condition20_and_verdict(capsys):
    assert main(["check", "paper-triangle3", "--trials", "64", "--base", "none"]) == 0
    out = capsys.readouterr().out
    assert "0.978306" in out and "verdict:" in out


def test_bad_scenario_is_one_clear_error(tmp_path):
    p = tmp_path / "bad.yaml"
    p.write_text(NO_TREE.replace("dt: 0.1", "dt: -1"))
    r = subprocess.run([sys.executable, "-m", "formation_ilc.cli", "simulate", str(p)],
                       capture_output=True, text=True)
    assert r.returncode == 2
    assert r.stderr.strip() == f"error: {p}: dt: the sample time must be > 0 s, got -1.0"


def test_help_teaches():
    r = subprocess.run([sys.executable, "-m", "formation_ilc.cli", "--help"],
                       capture_output=True, text=True)
    assert r.returncode == 0 and "examples:" in r.stdout
    r = subprocess.run([sys.executable, "-m", "formation_ilc.cli", "simulate", "--help"],
                       capture_output=True, text=True)
    assert "--memory" in r.stdout and "paper-notes 12" in r.stdout


def test_continue_from_a_learned_memory(tmp_path, capsys):
    a, b, full = tmp_path / "a", tmp_path / "b", tmp_path / "full"
    assert main(["simulate", "paper-triangle3", "--trials", "4", "--no-plots", "--out",
                 str(a)]) == 0
    assert main(["simulate", "paper-triangle3", "--trials", "3", "--no-plots", "--out", str(b),
                 "--init-memory", str(a / "memory.npz"), "--first-trial", "4"]) == 0
    assert main(["simulate", "paper-triangle3", "--trials", "7", "--no-plots", "--out",
                 str(full)]) == 0
    rows = lambda d: (d / "metrics.csv").read_text().splitlines()[1:]  # noqa: E731
    assert rows(a) + rows(b) == rows(full)
    assert main(["simulate", "paper-hexagon6", "--trials", "1", "--init-memory",
                 str(a / "memory.npz"), "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "memory.npz: learned for another run" in err
    assert "scenario 'paper-triangle3', this run 'paper-hexagon6'" in err and "3 robots" in err


def test_memory_file_is_versioned_checked_and_an_old_npy_still_reads(tmp_path):
    import numpy as np

    from formation_ilc.config.scenario import load_scenario, scenario_from_text
    from formation_ilc.store.memoryfile import MemoryFileError, load_memory, save_memory

    sc = load_scenario("paper-triangle3")
    mem = np.random.default_rng(0).normal(size=(sc.n, sc.samples, 2))
    path = save_memory(tmp_path / "m.npz", mem, sc, trials_learned=5)
    assert [p.name for p in tmp_path.iterdir()] == ["m.npz"]  # no temporary file left
    np.testing.assert_array_equal(load_memory(path, sc), mem)
    # options do not change the scenario's text: a noise-free run's memory fits a noisy one
    np.testing.assert_array_equal(load_memory(path, sc.with_options(noise=False, seed=3)), mem)
    edited = scenario_from_text(sc.text.replace("gain: 0.08", "gain: 0.07"), "edited.yaml")
    with pytest.raises(MemoryFileError, match=r"m\.npz: .*different text"):
        load_memory(path, edited)
    shorter = scenario_from_text(sc.text.replace("samples: 140", "samples: 100"), "s.yaml")
    with pytest.raises(MemoryFileError, match="140 samples, this run 100"):
        load_memory(path, shorter)
    np.save(tmp_path / "old.npy", mem)
    np.testing.assert_array_equal(load_memory(tmp_path / "old.npy", sc), mem)
    with pytest.raises(MemoryFileError, match=r"old\.npy: memory has shape"):
        load_memory(tmp_path / "old.npy", shorter)
    (tmp_path / "junk.npz").write_bytes(b"not a file")
    with pytest.raises(MemoryFileError, match="cannot read"):
        load_memory(tmp_path / "junk.npz", sc)


@pytest.mark.parametrize(("args", "message"), [
    (["--plant", "pioneer", "--mode", "lockstep"], "--plant pioneer runs --mode wallclock"),
    (["--plant", "pioneer", "--links", "emulated"], "with --links direct"),
    (["--mode", "wallclock"], "--mode wallclock is for real robots"),
    (["--fake-drivers"], "--fake-drivers goes with --plant pioneer"),
    (["--plant", "pioneer", "--fake-drivers", "--driver", "p2os2"], "not p2os2"),
])
def test_launch_refuses_a_real_robot_run_it_cannot_do(tmp_path, capsys, args, message):
    assert main(["launch", "paper-triangle3", "--out", str(tmp_path), *args]) == 2
    assert message in capsys.readouterr().err


def test_simulate_on_a_full_disk_is_one_line_naming_the_file_and_status_5(tmp_path, capsys):
    """Before: exit 1, a status simulate does not document. metrics.csv here is the full
    device (every write fails with ENOSPC, as on a full disk)."""
    import os

    if not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full here")
    out = tmp_path / "run"
    out.mkdir()
    (out / "metrics.csv").symlink_to("/dev/full")
    assert main(["simulate", "paper-triangle3", "--trials", "2", "--out", str(out),
                 "--no-plots"]) == 5
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: the disk is full: simulate could not write {out}/metrics.csv; "
                   f"what was written before is kept; free some space, then run it again"]
