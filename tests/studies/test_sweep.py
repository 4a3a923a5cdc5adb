"""Sweeps: strict specs, stable point ids, the local pool, resuming after SIGKILL."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from formation_ilc.config.scenario import ScenarioError
from formation_ilc.studies.study import apply_fields, point_id, reduce_metrics, settle_trial
from formation_ilc.studies.sweep import load_spec, read_table, run_sweep, spec_from_text

# the hexagon loads in milliseconds (the triangle's unicycle reference takes 0.3 s)
SPEC = """\
scenario: paper-hexagon6
trials: 12
seeds: [1, 2]
floor_window: 5
check: false
grid:
  law.gain: [0.08, 0.4]
  law.gain_prime: [0.08, 0.4]
"""


def _spec(tmp_path: Path, text: str = SPEC, name: str = "spec.yaml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("text, where", [
    ("scenario: paper-hexagon6\ngrid: {law.gains: [1]}\n", "grid.law.gains"),
    ("scenario: paper-hexagon6\ngrid: {law.gain: 1}\n", "grid.law.gain"),
    ("scenario: paper-hexagon6\ngrid: {law.kind: [9, 24]}\n", "law.kind"),
    ("scenario: paper-hexagon6\ngrid: {law.gain: [0.1, -1]}\n", "law.gain"),
    ("scenario: paper-hexagon6\ngrid: {law.gain: [[1, 2]]}\n", "law.gain"),
    ("scenario: paper-hexagon6\ngrid: {delay: [sometimes]}\n", "delay.model"),
    ("scenario: paper-hexagon6\ngrid: {noise_scale: [-1]}\n", "noise_scale"),
    ("scenario: paper-hexagon6\ngrid: {graph: [{leader: {7: 1}}]}\n", "graph.leader.7"),
    ("scenario: paper-hexagon6\nseeds: [1, 1]\ngrid: {law.gain: [1]}\n", "seeds"),
    ("scenario: paper-hexagon6\nseeds: [x]\ngrid: {law.gain: [1]}\n", "seeds[0]"),
    ("scenario: paper-hexagon6\ntrials: 0\ngrid: {law.gain: [1]}\n", "trials"),
    ("scenario: paper-hexagon6\ntrails: 3\ngrid: {law.gain: [1]}\n", "trails"),
    ("scenario: paper-hexagon6\n", "top level"),
    ("scenario: nowhere\ngrid: {law.gain: [1]}\n", "scenario"),
    ("scenario: paper-hexagon6\nrandom: {count: 2, fields: {law.gain: {uniform: [2, 1]}}}\n",
     "random.fields.law.gain.uniform"),
    ("scenario: paper-hexagon6\nrandom: {count: 2, fields: {law.gain: {normal: [0, 1]}}}\n",
     "random.fields.law.gain"),
])
def test_spec_errors_name_file_and_field(tmp_path, text, where):
    p = _spec(tmp_path, text)
    with pytest.raises(ScenarioError) as err:
        load_spec(p)
    msg = str(err.value)
    assert msg.startswith(str(p)), msg
    assert where in msg, msg


def test_random_spec_is_reproducible(tmp_path):
    text = ("scenario: paper-hexagon6\nrandom:\n  count: 4\n  seed: 3\n  fields:\n"
            "    law.gain: {log_uniform: [0.05, 1]}\n    law.kind: {choice: [9, 22]}\n")
    a = spec_from_text(text, "a.yaml")
    b = spec_from_text(text, "b.yaml")
    assert a.configs == b.configs and len(a.configs) == 4
    assert all(0.05 <= c["law.gain"] <= 1 for c in a.configs)
    assert {c["law.kind"] for c in a.configs} <= {9, 22}


def test_point_ids_stable_and_distinct():
    sc_text = "name: x\n"
    a = point_id(sc_text, {"law.gain": 0.1}, 10, 1)
    assert a == point_id(sc_text, {"law.gain": 0.1}, 10, 1)
    assert len({a, point_id(sc_text, {"law.gain": 0.1}, 10, 2),
                point_id(sc_text, {"law.gain": 0.2}, 10, 1),
                point_id(sc_text, {"law.gain": 0.1}, 11, 1),
                point_id(sc_text + " ", {"law.gain": 0.1}, 10, 1)}) == 5


def test_fields_change_the_scenario():
    from formation_ilc.config.scenario import load_scenario

    base = load_scenario("paper-hexagon6")
    sc = apply_fields(base.text, {"law.gain": [0.1, 0.2, 0.3, 0.4, 0.5, 0.6], "law.kind": 22,
                                  "delay": "none", "noise_scale": 0.0}, seed=4, trials=7)
    assert sc.law.gain == (0.1, 0.2, 0.3, 0.4, 0.5, 0.6) and sc.law.kind == 22
    assert sc.uncertainty.delay.kind == "none" and not sc.uncertainty.noisy
    assert (sc.seed, sc.trials) == (4, 7)
    half = apply_fields(base.text, {"noise_scale": 0.5})
    assert half.uncertainty.noise_uniform[0] == pytest.approx(
        0.5 * base.uncertainty.noise_uniform[0])
    assert half.uncertainty.delay == base.uncertainty.delay


def test_reduce_and_settle():
    import numpy as np

    assert settle_trial(np.array([3.0, 0.5, 2.0, 0.5, 0.4]), 1.0) == 3
    assert settle_trial(np.array([0.5, 0.4]), 1.0) == 0
    assert settle_trial(np.array([0.5, 2.0]), 1.0) is None
    m = np.zeros((4, 7))
    m[:, 1] = [2.0, 3.0, 0.5, 0.4]
    m[:, 2] = [1.0, 0.5, 0.05, 0.2]
    row = reduce_metrics(m, 1.0, 0.1, 2)
    assert row["peak_position"] == 3.0 and row["peak_trial"] == 1 and row["above_trial0"] == 1
    assert row["trials_to_position"] == 2 and row["trials_to_heading"] is None
    assert row["floor_position"] == pytest.approx(0.45)


def test_pool_table_equals_serial_table(tmp_path):
    spec = load_spec(_spec(tmp_path))
    serial = run_sweep(spec, tmp_path / "serial", workers=1, progress=False)
    pooled = run_sweep(spec, tmp_path / "pool", workers=2, progress=False, keep_pool=True)
    assert serial.read_bytes() == pooled.read_bytes()
    rows = read_table(serial)
    assert len(rows) == 8
    # the gain changes the result: the table is not a constant
    assert len({r["trials_to_position"] + r["floor_position"] for r in rows}) > 2
    # small points travel several to a task (chunk_tasks): the same table
    many = load_spec(_spec(tmp_path, SPEC.replace("seeds: [1, 2]", "seeds: {first: 1, "
                                                  "count: 10}").replace("trials: 12",
                                                                        "trials: 6"), "m.yaml"))
    from formation_ilc.studies.sweep import chunk_tasks

    assert max(len(c) for c in chunk_tasks(many.sim_tasks(), 2)) == 3
    serial = run_sweep(many, tmp_path / "serial-m", workers=1, progress=False)
    pooled = run_sweep(many, tmp_path / "pool-m", workers=2, progress=False)
    assert serial.read_bytes() == pooled.read_bytes()
    assert len(read_table(serial)) == 40


def test_resume_skips_done_points(tmp_path):
    spec = load_spec(_spec(tmp_path))
    out = tmp_path / "out"
    ran: list[str] = []
    run_sweep(spec, out, workers=1, progress=False, on_row=lambda r: ran.append(r["id"]))
    assert len(ran) == 8
    first = (out / "results.csv").read_bytes()
    gone = sorted((out / "points").glob("*.json"))[:3]
    for p in gone:
        p.unlink()
    ran.clear()
    run_sweep(spec, out, workers=1, progress=False, on_row=lambda r: ran.append(r["id"]))
    assert sorted(ran) == sorted(p.stem for p in gone)
    assert (out / "results.csv").read_bytes() == first


def test_sigkill_midway_then_resume_gives_the_same_table(tmp_path):
    # one process, enough points that the kill lands midway
    text = SPEC.replace("trials: 12", "trials: 100").replace("seeds: [1, 2]",
                                                            "seeds: [1, 2, 3, 4, 5, 6]")
    spec_path = _spec(tmp_path, text)
    ref = run_sweep(load_spec(spec_path), tmp_path / "ref", workers=1, progress=False)
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "formation_ilc.cli", "sweep", str(spec_path), "--out", str(out),
           "--workers", "1", "--no-plots"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env={**os.environ, "MPLBACKEND": "Agg"})
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            if len(list((out / "points").glob("*.json"))) >= 5 or proc.poll() is not None:
                break
            time.sleep(0.01)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL, "the sweep finished before it was killed"
    done = {p.name: p.stat().st_mtime_ns for p in (out / "points").glob("*.json")}
    assert 5 <= len(done) < 24
    assert not (out / "results.csv").exists()
    rerun = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert rerun.returncode == 0, rerun.stderr
    # points finished before the kill were kept, not recomputed
    assert all((out / "points" / n).stat().st_mtime_ns == t for n, t in done.items())
    assert (out / "results.csv").read_bytes() == ref.read_bytes()


def test_cli_sweep_writes_table_and_plots(tmp_path):
    from formation_ilc.cli import main

    p = _spec(tmp_path)
    assert main(["sweep", str(p), "--out", str(tmp_path / "o"), "--workers", "1"]) == 0
    assert (tmp_path / "o" / "results.csv").is_file()
    assert (tmp_path / "o" / "heatmap_trials_to_position.png").is_file()
    assert (tmp_path / "o" / "lines_trials_to_position.png").is_file()
    assert main(["sweep", str(_spec(tmp_path, "scenario: 3\n", "bad.yaml")), "--out",
                 str(tmp_path / "b")]) == 2


FIELD_CASES = [
    {"law.gain": 0.4},
    {"law.gain": [0.1, 0.2, 0.3, 0.4, 0.5, 0.6], "law.gain_prime": 1.5, "law.kind": 23},
    {"law.memory": "literal", "delay": "none"},
    {"delay": {"model": "uniform", "low": 1, "high": 3}, "graph": {
        "leader": {1: 1.0}, "edges": [{"from": 1, "to": k} for k in range(2, 7)]}},
    {"law.gain": 1e-05, "law.gain_prime": 2.0},
]


@pytest.mark.parametrize("fields", FIELD_CASES)
def test_fields_applied_to_the_data_equal_the_written_scenario(fields):
    """apply_fields validates the edited data without writing it out and parsing it again:
    the same scenario as loading the text scenario_text_with writes."""
    import numpy as np

    from formation_ilc.config.scenario import load_scenario, scenario_from_text
    from formation_ilc.studies.study import scenario_text_with

    base = load_scenario("paper-hexagon6")
    got = apply_fields(base.text, fields, "p.yaml", seed=3, trials=5)
    ref = scenario_from_text(scenario_text_with(base.text, fields), "p.yaml").with_options(
        seed=3, trials=5)
    for f in ("name", "dt", "samples", "trials", "seed", "frame", "scales", "law",
              "uncertainty", "source"):
        assert getattr(got, f) == getattr(ref, f), f
    for f in ("reference", "offsets"):
        assert getattr(got, f).tobytes() == getattr(ref, f).tobytes()
    assert got.graph.adjacency.tobytes() == ref.graph.adjacency.tobytes()
    assert got.graph.leader.tobytes() == ref.graph.leader.tobytes()
    if "graph" in fields:
        assert np.count_nonzero(got.graph.adjacency) == 5  # the field was applied
    assert got.desired.eta.tobytes() == ref.desired.eta.tobytes()


def test_a_sweep_row_is_the_simulate_commands_run(tmp_path):
    """A point's row reduces exactly what `formation-ilc simulate` computes for the scenario
    with the point's fields and seed (its metrics.csv, read back)."""
    from formation_ilc.cli import main
    from formation_ilc.config.scenario import load_scenario
    from formation_ilc.core.metrics import read_metrics
    from formation_ilc.studies.study import run_sim_point, scenario_text_with

    spec = load_spec(_spec(tmp_path))
    task = spec.sim_tasks()[5]
    row = run_sim_point(task)
    sc_file = tmp_path / "point.yaml"
    sc_file.write_text(scenario_text_with(load_scenario("paper-hexagon6").text, task["fields"]))
    assert main(["simulate", str(sc_file), "--trials", str(task["trials"]), "--seed",
                 str(task["seed"]), "--no-plots", "--out", str(tmp_path / "sim")]) == 0
    metrics = read_metrics(tmp_path / "sim" / "metrics.csv")
    ref = reduce_metrics(metrics, task["position_level"], task["heading_level"],
                         task["floor_window"])
    assert {k: row[k] for k in ref} == ref
    assert row["robot_samples"] == 6 * 300 * task["trials"]


def test_chunks_keep_the_order_and_bound_the_work():
    from formation_ilc.studies.sweep import CHUNK_ROBOT_SAMPLES, chunk_tasks

    base = SPEC.replace("check: false", "check: true")
    spec = spec_from_text(base.replace("seeds: [1, 2]", "seeds: {first: 1, count: 30}"))
    tasks = spec.check_tasks() + spec.sim_tasks()
    chunks = chunk_tasks(tasks, workers=2)
    assert [t["id"] for c in chunks for t in c] == [t["id"] for t in tasks]
    assert all(len(c) == 1 for c in chunks if c[0]["id"].startswith("check-"))
    assert not any(t["id"].startswith("check-") for c in chunks if len(c) > 1 for t in c)
    # 120 small points (6 x 300 x 12 robot-samples): as many per chunk as leaves 8 per worker
    sims = [c for c in chunks if not c[0]["id"].startswith("check-")]
    assert max(len(c) for c in sims) == 8 and len(sims) == 15
    big = spec_from_text(base.replace("trials: 12", "trials: 300"))
    assert all(len(c) == 1 for c in chunk_tasks(big.sim_tasks(), 1))  # 540k robot-samples
    assert 2 * 6 * 300 * 300 > CHUNK_ROBOT_SAMPLES


def test_points_finished_before_an_interrupt_are_written(tmp_path, monkeypatch):
    spec = load_spec(_spec(tmp_path))
    out = tmp_path / "out"
    seen: list[str] = []

    def stop(row):
        seen.append(row["id"])
        if len(seen) == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_sweep(spec, out, workers=1, progress=False, on_row=stop)
    assert sorted(p.stem for p in (out / "points").glob("*.json")) == sorted(seen)


def test_a_write_error_stops_the_sweep(tmp_path, monkeypatch):
    from formation_ilc.studies import sweep

    spec = load_spec(_spec(tmp_path))
    calls: list[str] = []
    real = sweep._write_atomic

    def failing(path, row):
        calls.append(row["id"])
        if len(calls) == 2:
            raise OSError(28, "No space left on device")
        real(path, row)

    monkeypatch.setattr(sweep, "_write_atomic", failing)
    with pytest.raises(OSError, match="No space"):
        run_sweep(spec, tmp_path / "out", workers=1, progress=False)
    assert not (tmp_path / "out" / "results.csv").exists()
    assert len(list((tmp_path / "out" / "points").glob("*.json"))) == 1


def _blas_threads() -> list[int]:
    from threadpoolctl import threadpool_info

    return [lib["num_threads"] for lib in threadpool_info()]


def test_pool_workers_run_blas_on_one_thread():
    """The workers are the parallelism: a BLAS thread pool in each would oversubscribe."""
    from formation_ilc.studies.sweep import _pool, close_pools

    try:
        threads = _pool(2).submit(_blas_threads).result(timeout=120)
    finally:
        close_pools()
    assert threads and set(threads) == {1}


def test_exponent_numbers_survive_writing_a_configuration_into_a_scenario():
    """``1e-3`` is a number for the scenario loader (YAML 1.2); the study's own rewriting of
    the text must read it the same way, not as a string."""
    from formation_ilc.config.scenario import load_scenario, scenario_from_text
    from formation_ilc.studies.study import scenario_text_with

    text = load_scenario("paper-triangle3").text.replace("dt: 0.2", "dt: 2e-1")
    assert "2e-1" in text
    out = scenario_text_with(text, {"law.gain": 0.5})
    assert scenario_from_text(out, "x").dt == 0.2
