"""Hostile and mistaken input to the command line and the numerical core (issue 8).

Each case answers with one clear line (file or option, field, why) and a documented exit
status, within bounded time and memory: never a traceback, a hang or silent data loss.
"""

from __future__ import annotations

import csv
import os
import re
import signal
import subprocess
import sys
import time
import zipfile

import numpy as np
import pytest
import yaml

from formation_ilc.cli.commands import (
    CHECK_DIVERGES,
    CHECK_LIMITS,
    CHECK_OK,
    CHECK_TRANSIENT,
    CHECK_UNKNOWN,
    check_status,
    main,
)
from formation_ilc.cli.simulate import MemoryKeeper, TrialLog
from formation_ilc.config.scenario import (
    MAX_FILE_BYTES,
    MAX_YAML_DEPTH,
    ScenarioError,
    load_scenario,
    scenario_from_text,
)
from formation_ilc.core import guards
from formation_ilc.core.guards import DivergedError, check_finite
from formation_ilc.core.metrics import METRIC_COLUMNS
from formation_ilc.model.simulate import simulate
from formation_ilc.store.memoryfile import MemoryFileError, load_memory, save_memory

TRIANGLE = load_scenario("paper-triangle3").text

BOMB = """\
a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]
b: &b [*a,*a,*a,*a,*a,*a,*a,*a,*a]
c: &c [*b,*b,*b,*b,*b,*b,*b,*b,*b]
d: &d [*c,*c,*c,*c,*c,*c,*c,*c,*c]
e: &e [*d,*d,*d,*d,*d,*d,*d,*d,*d]
f: &f [*e,*e,*e,*e,*e,*e,*e,*e,*e]
g: &g [*f,*f,*f,*f,*f,*f,*f,*f,*f]
h: &h [*g,*g,*g,*g,*g,*g,*g,*g,*g]
i: &i [*h,*h,*h,*h,*h,*h,*h,*h,*h]
name: *i
"""


def _with(text: str, **fields: str) -> str:
    """``text`` with top-level or law lines replaced, e.g. samples="1000"."""
    for key, value in fields.items():
        text, n = re.subn(rf"^(\s*){key}:.*$", rf"\g<1>{key}: {value}", text, count=1,
                          flags=re.M)
        assert n == 1, key
    return text


def _cli(*argv: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "formation_ilc.cli", *argv],
                          capture_output=True, text=True, timeout=timeout)


@pytest.fixture
def little_memory(monkeypatch):
    """The machine has 8 MiB available, as far as the estimates can tell."""
    monkeypatch.setattr(guards, "available_memory", lambda: (8 << 20, "MemAvailable"))


# --------------------------------------------------------------------------- scenario files

def test_binary_junk_is_named_as_such(tmp_path):
    p = tmp_path / "junk.yaml"
    p.write_bytes(b"\x7fELF\x02\x01\xf6\x00" + bytes(range(256)) * 8)
    r = _cli("check", str(p))
    assert r.returncode == 2
    assert r.stderr == (f"error: {p}: not a text file: byte 0xf6 at offset 6 is not UTF-8 "
                        f"(a scenario file is YAML text)\n")


def test_nul_bytes_in_utf8_are_not_text(tmp_path):
    p = tmp_path / "nul.yaml"
    p.write_bytes(b"name: a\x00b\n")
    with pytest.raises(ScenarioError, match=r"nul\.yaml: not a text file: it holds NUL bytes "
                                            r"at offset 7"):
        load_scenario(p)


def test_billion_laughs_is_refused_unbuilt(tmp_path):
    """Before: 3.5 GB of memory, then MemoryError (the error message expanded the aliases)."""
    p = tmp_path / "bomb.yaml"
    p.write_text(BOMB)
    r = _cli("check", str(p))
    assert r.returncode == 2
    assert r.stderr == (f"error: {p}: g[7]: the aliases (*name) expand the document beyond "
                        f"16.8 million nodes and characters (a 'billion laughs'?); refused\n")


def test_recursive_alias_and_deep_nesting_are_refused():
    with pytest.raises(ScenarioError, match=r"^r\.yaml: a\[0\]: alias \*a refers to a "
                                            r"collection that contains it \(recursive\)"):
        scenario_from_text("a: &a [*a]\nname: *a\n", "r.yaml")
    deep = "name: " + "[" * 1000 + "]" * 1000 + "\n"  # libyaml's composer: a stack overflow
    with pytest.raises(ScenarioError, match=rf"^d\.yaml: line 1: name[\[\]0]+\.\.\.: nested deeper "
                                            rf"than {MAX_YAML_DEPTH} levels; refused$"):
        scenario_from_text(deep, "d.yaml")


def test_a_file_too_large_is_refused_before_it_is_read(tmp_path):
    p = tmp_path / "big.yaml"
    p.write_text("# " + "x" * MAX_FILE_BYTES)
    with pytest.raises(ScenarioError, match=r"big\.yaml: larger than 1 MiB, the most a scenario "
                                            r"file may be \(a long sampled reference belongs "
                                            r"in a CSV file: reference\.file\)"):
        load_scenario(p)


def test_yaml_errors_are_one_line_with_the_line_number():
    with pytest.raises(ScenarioError) as exc:
        scenario_from_text("name: x\n  dt: : [\n", "bad.yaml")
    assert str(exc.value) == ("bad.yaml: not valid YAML: line 2, column 5: mapping values are "
                              "not allowed in this context")
    with pytest.raises(ScenarioError, match=r"^d\.yaml: not valid YAML: month must be in 1\.\.12"):
        scenario_from_text("name: x\ndt: 2024-13-45\n", "d.yaml")


def test_error_values_are_shown_cut_short():
    text = _with(TRIANGLE, name="[" + ", ".join(["'lol'"] * 100_000) + "]")
    with pytest.raises(ScenarioError) as exc:
        scenario_from_text(text, "s.yaml")
    msg = str(exc.value)
    assert msg.startswith("s.yaml: name: expected a string, got ['lol', 'lol'")
    assert len(msg) < 200


def test_exponent_floats_read_as_numbers():
    sc = scenario_from_text(_with(TRIANGLE, gain="1e300"), "g.yaml")
    assert sc.law.gain == (1e300,) * 3


def test_names_that_are_paths_are_refused():
    with pytest.raises(ScenarioError, match=r"s\.yaml: name: names the output folder: no '/'"):
        scenario_from_text(_with(TRIANGLE, name="../../etc"), "s.yaml")


def test_samples_beyond_memory_are_refused_before_allocation(little_memory):
    with pytest.raises(ScenarioError) as exc:
        scenario_from_text(_with(TRIANGLE, samples="1000000"), "t.yaml")
    assert str(exc.value) == ("t.yaml: samples: 3 robots x 1000000 samples: loading them needs "
                              "about 153 MiB, 8 MiB available (MemAvailable)")


def test_extreme_reference_is_not_a_scenario():
    with pytest.raises(ScenarioError, match=r"^t\.yaml: reference: the unicycle reference is not "
                                            r"finite from sample 1 on"):
        scenario_from_text(_with(TRIANGLE, turn_radius="1e-320"), "t.yaml")


def test_unicycle_reference_is_the_loop_bit_for_bit():
    from formation_ilc.core import trajectory as tr

    v = tr.paper_ivb_speed
    for m, radius, sub in ((142, 1.5, 32), (300, -2.0, 7), (2, 1.0, 32)):
        a = tr._unicycle_reference_loop(v, lambda t, r=radius: v(t) / r, m, 0.2, (1, 2, 0.3),
                                        sub)
        b = tr.unicycle_reference(v, lambda t, r=radius: v(t) / r, m, 0.2, (1, 2, 0.3), sub)
        np.testing.assert_array_equal(a, b)


# --------------------------------------------------------------------------- options

@pytest.mark.parametrize(("argv", "message"), [
    (["simulate", "paper-triangle3", "--seed", "-1"],
     "error: argument --seed: must be an integer >= 0, got -1 (see formation-ilc simulate "
     "--help)"),
    (["check", "paper-triangle3", "--trials", "0"],
     "error: argument --trials: must be an integer >= 1, got 0 (see formation-ilc check "
     "--help)"),
    (["compare", "paper-triangle3", "--trials", "x"],
     "error: argument --trials: expected an integer, got 'x' (see formation-ilc compare --help)"),
    (["tune", "paper-triangle3", "--workers", "0"],
     "error: argument --workers: must be an integer in 1..4096, got 0 (see formation-ilc tune "
     "--help)"),
    (["launch", "paper-triangle3", "--seed", "-1"],
     "error: argument --seed: must be an integer >= 0, got -1 (see formation-ilc launch --help)"),
    (["launch", "paper-triangle3", "--domain-id", "300"],
     "error: argument --domain-id: must be an integer <= 232, got 300 (see formation-ilc "
     "launch --help)"),
    (["tune", "paper-triangle3", "--position-level", "nan"],
     "error: argument --position-level: must be a finite number > 0, got nan (see "
     "formation-ilc tune --help)"),
])
def test_bad_option_values_are_one_line(capsys, argv, message):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert capsys.readouterr().err == message + "\n"


def test_out_on_a_file_or_an_unwritable_path(tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_text("keep me")
    with pytest.raises(SystemExit) as exc:
        main(["simulate", "paper-triangle3", "--out", str(afile)])
    assert exc.value.code == 2
    assert capsys.readouterr().err == (f"error: argument --out: {afile}: exists and is not a "
                                       f"folder (see formation-ilc simulate --help)\n")
    assert afile.read_text() == "keep me"
    with pytest.raises(SystemExit):
        main(["simulate", "paper-triangle3", "--out", str(afile / "sub")])
    assert f"{afile} is not a folder" in capsys.readouterr().err
    # a folder no one can create (passes the parse-time check as root): caught at mkdir
    assert main(["simulate", "paper-triangle3", "--trials", "1", "--out", "/proc/nope"]) == 2
    assert capsys.readouterr().err == ("error: --out /proc/nope: cannot write there: No such "
                                       "file or directory\n")


def test_gain_grid_nan_is_refused(capsys):
    """Before: nan passed `min(grid) <= 0` and numpy's SVD failed with a traceback."""
    assert main(["tune", "paper-triangle3", "--gain-grid", "nan", "--out", "/tmp"]) == 2
    assert capsys.readouterr().err == ("error: --gain-grid: values must be finite and > 0, got "
                                       "'nan'\n")


def test_sweep_metric_is_checked_before_the_study_runs(tmp_path, capsys):
    spec = tmp_path / "s.yaml"
    spec.write_text("scenario: paper-triangle3\ntrials: 2\ngrid: {law.gain: [0.08]}\n")
    assert main(["sweep", str(spec), "--metric", "nope", "--out", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err.startswith("error: --metric: no column 'nope' (columns: ")
    assert not (tmp_path / "o").exists()


def test_a_memory_file_that_is_a_device(tmp_path, capsys):
    """Before: /dev/zero as --init-memory ran out of memory."""
    assert main(["simulate", "paper-triangle3", "--init-memory", "/dev/zero", "--out",
                 str(tmp_path)]) == 2
    assert capsys.readouterr().err == ("error: /dev/zero: cannot read a memory file: not a "
                                       "regular file\n")


def test_a_file_that_is_not_a_recording(tmp_path, capsys):
    p = tmp_path / "junk.mcap"
    p.write_bytes(b"\x89not an mcap file at all")
    assert main(["analyze", str(p), "--out", str(tmp_path / "a")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {p}") and err.count("\n") == 1


def test_sweep_spec_junk_and_bomb(tmp_path, capsys):
    p = tmp_path / "spec.yaml"
    p.write_bytes(b"\xff\xfe" + "scenario: x".encode("utf-16-le"))
    assert main(["sweep", str(p), "--out", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err == (f"error: {p}: not a text file: byte 0xff at offset 0 is "
                                       f"not UTF-8 (a sweep spec file is YAML text)\n")
    p.write_text(BOMB.replace("name: *i", "scenario: *i"))
    assert main(["sweep", str(p), "--out", str(tmp_path / "o")]) == 2
    assert "expand the document beyond" in capsys.readouterr().err


# --------------------------------------------------------------------------- memory

def test_a_run_that_would_not_fit_is_refused_with_its_estimate(little_memory, tmp_path, capsys):
    p = tmp_path / "long.yaml"
    p.write_text(_with(TRIANGLE, samples="20000"))
    assert main(["simulate", str(p), "--out", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err == (
        f"error: {p}: samples: a run keeping 4 trials' trajectories of 3 robots x 20000 samples "
        f"needs about 31.1 MiB, 8 MiB available (MemAvailable); use fewer samples (or robots, "
        f"or kept trials)\n")
    assert not (tmp_path / "o").exists()  # refused before anything was written


def test_metrics_are_streamed_in_bounded_memory(tmp_path):
    """A run of many trials keeps at most ``cap`` rows for its plot; the csv gets them all."""
    log = TrialLog(tmp_path / "m.csv", cap=8)
    for k in range(1000):
        log.add(np.array([k, 1000.0 - k if k != 500 else 0.5, 0, 0, 0, 0, 0, 0, np.nan]))
    log.close()
    rows = log.rows()
    assert len(rows) <= 9 and rows[0, 0] == 0 and rows[-1, 0] == 999
    assert log.best is not None and log.best[0] == 500
    assert len((tmp_path / "m.csv").read_text().splitlines()) == 1001


def test_simulate_stores_no_metrics_when_asked():
    sc = load_scenario("paper-triangle3").with_options(noise=False, delay=False)
    seen: list[float] = []
    res = simulate(sc, trials=3, progress=lambda k, row: seen.append(row[1]),
                   store_metrics=False)
    assert res.metrics.shape == (0, len(METRIC_COLUMNS)) and len(seen) == 3
    full = simulate(sc, trials=3)
    np.testing.assert_array_equal(full.column("max_position_error"), seen)


# --------------------------------------------------------------------------- divergence

def test_a_diverging_run_stops_and_keeps_the_finished_trials(tmp_path):
    """Before: gain 1e300 ran every trial in inf/nan and exited 0."""
    p = tmp_path / "g.yaml"
    p.write_text(_with(TRIANGLE, gain="1e300"))
    out = tmp_path / "o"
    r = _cli("simulate", str(p), "--trials", "30", "--no-plots", "--out", str(out))
    assert r.returncode == 3
    assert r.stderr.splitlines()[-1] == (
        f"error: {p}: trial 1: robot 1's max position error is not finite (inf or nan): the "
        f"learning diverged; metrics.csv keeps trials 0..0, memory.npz the memory trial 1 "
        f"started from (in {out}/); smaller gains? see `formation-ilc check {p}`")
    rows = list(csv.DictReader((out / "metrics.csv").open()))
    assert [row["trial"] for row in rows] == ["0"]
    with np.load(out / "memory.npz") as data:
        assert int(data["trials_learned"]) == 1
        assert np.isfinite(data["memory"]).all()
    # finite but far beyond any robot's command: loading it again is refused in one line
    with pytest.raises(MemoryFileError, match=r"robot 1's v at sample 0 is .*beyond 1e\+06"):
        load_memory(out / "memory.npz", load_scenario(p))


def test_divergence_check_names_trial_robot_and_quantity():
    eta = np.zeros((3, 5, 3))
    check_finite(4, np.zeros(7), output=eta)
    eta[1, 2, 0] = np.nan
    with pytest.raises(DivergedError, match=r"^trial 4: robot 2's output is not finite"):
        check_finite(4, output=eta)
    row = np.array([4, np.inf, 0, np.nan, np.nan, 0, 0])  # true_ columns may be nan
    with pytest.raises(DivergedError, match=r"^trial 4: max position error is not finite"):
        check_finite(4, row)
    check_finite(4, np.array([4, 1, 0, np.nan, np.nan, 0, 0]))  # a plant without truth


def test_simulate_reports_the_last_finite_memory_on_divergence():
    sc = scenario_from_text(_with(TRIANGLE, gain="1e300"), "g.yaml").with_options(
        noise=False, delay=False)
    with pytest.raises(DivergedError) as exc:
        simulate(sc, trials=10, stop_on_divergence=True)
    assert exc.value.trial == 1 and exc.value.result.metrics.shape == (1, len(METRIC_COLUMNS))
    assert np.isfinite(exc.value.result.memory).all()


# --------------------------------------------------------------------------- check's status

class _Map:
    def __init__(self, norm: float, rho: float, growth: float):
        self.norm, self.spectral_radius, self.growth = norm, rho, growth


class _Report:
    def __init__(self, tree: bool = True, cond20: float = 0.9, heading: _Map | None = None):
        self.spanning_tree, self.cond20, self.heading = tree, cond20, heading


@pytest.mark.parametrize(("report", "status"), [
    (_Report(heading=_Map(0.9, 0.9, 0.9)), CHECK_OK),
    (_Report(heading=_Map(1.2, 0.99, 6.0)), CHECK_OK),  # a mild transient
    (_Report(heading=_Map(1.6, 0.99, 3e9)), CHECK_TRANSIENT),
    (_Report(heading=_Map(2.0, 1.0, 1e9)), CHECK_DIVERGES),
    (_Report(cond20=1.1, heading=_Map(0.9, 0.9, 0.9)), CHECK_DIVERGES),
    (_Report(), CHECK_UNKNOWN),
    (_Report(tree=False), 2),
])
def test_check_status_is_the_verdict(report, status):
    assert check_status(report) == status


def test_check_exits_with_its_verdict(tmp_path, capsys):
    """Before: 'will not converge' printed, exit 0."""
    p = tmp_path / "g.yaml"
    p.write_text(_with(TRIANGLE, gain="50"))
    assert main(["check", str(p), "--trials", "8"]) == CHECK_DIVERGES
    assert "verdict: will not converge" in capsys.readouterr().out
    p.write_text(_with(TRIANGLE, samples="1300"))  # 3 x 1300 > 3600: the lifted map is skipped
    assert main(["check", str(p), "--base", "none"]) == CHECK_UNKNOWN
    assert main(["check", "paper-triangle3", "--trials", "8", "--base", "none"]) == CHECK_OK
    # on Pioneers the safety filter trims its own motion where robot 3 catches up with
    # robot 1 (0.3 m/s^2 of braking), tried with the scenario's own noise (the room the
    # filter keeps for it, tried on it): 6, and what fits; two thirds as fast fits
    assert main(["check", "paper-triangle3", "--trials", "8"]) == CHECK_LIMITS
    err = capsys.readouterr().err
    assert "changes the desired motion itself" in err and "robots 1 and 3" in err
    assert "poses as noisy as the scenario's" in err and "speeds told" in err
    assert "what fits: --time-scale 1.5 (slower)" in err
    assert main(["check", "paper-triangle3", "--trials", "8", "--time-scale", "2"]) == CHECK_OK


UNTUNED = """\
name: untuned-corners
dt: 0.2
samples: 100
trials: 10
robots: 4
reference:
  kind: waypoints
  times: [0, 5, 10, 20]
  points: [[0, 0], [3, 0], [3, 3], [0, 3]]
formation:
  frame: leader
  offsets:
    1: {x: 1.5, y: 0.0}
    2: {x: 0.0, y: 1.5}
    3: {x: -1.5, y: 0.0}
    4: {x: 0.0, y: -1.5}
graph:
  leader: {1: 1.0}
  edges: [{from: 1, to: 2}, {from: 2, to: 3}, {from: 3, to: 4}]
law: {kind: 9, memory: feedforward, gain: 0.08, gain_prime: 0.08, gain_heading: measured}
"""


def test_check_fails_a_scenario_whose_motion_leaves_the_base_limits(tmp_path, capsys):
    """Before: 'converges' (exit 0) for waypoints with corners whose desired speed reaches
    metres a second; now every robot's peaks are printed and the run exits 6 naming the
    robot and the time scale that fits."""
    p = tmp_path / "untuned.yaml"
    p.write_text(UNTUNED)
    status = main(["check", str(p)])
    out, err = capsys.readouterr()
    assert status == CHECK_LIMITS
    assert out.count("peak speed") == 4 and "largest step" in out
    (line,) = [x for x in err.splitlines() if x.startswith("error: p3dx: robot")]
    assert "exceeds its limit" in line
    # the learning alone passes
    assert main(["check", str(p), "--base", "none"]) == CHECK_OK
    capsys.readouterr()
    # the corners turn the leader-frame formation in one sample: the outer robots jump 2 m
    # between two samples, which no time scale and no base's limits make good
    assert main(["check", str(p), "--base", "jackal", "--time-scale", "4"]) == CHECK_LIMITS
    out, err = capsys.readouterr()
    assert "time scale 4" in out and "largest step 2.1" in out
    assert "no time scale up to 20 fits" in err


# --------------------------------------------------------------------------- interruption

def test_sigterm_keeps_the_metrics_and_the_memory_and_says_how_to_go_on(tmp_path):
    """Before: an interrupted simulate wrote no memory file."""
    out = tmp_path / "o"
    args = ["paper-triangle3", "--no-noise", "--no-delay", "--no-plots"]
    proc = subprocess.Popen([sys.executable, "-m", "formation_ilc.cli", "simulate", *args,
                             "--trials", "1000000", "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        # a hang guard: the batch simulator compiles first when the kernels' cache is cold
        # (a changed tree), minutes under a loaded suite
        deadline = time.monotonic() + 900
        metrics = out / "metrics.csv"
        while not (metrics.exists() and len(metrics.read_text().splitlines()) > 5):
            assert proc.poll() is None, proc.communicate()[1]
            assert time.monotonic() < deadline, "no trial row in 900 s"
            time.sleep(0.05)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 128 + signal.SIGTERM, err
    rows = (out / "metrics.csv").read_text().splitlines()[1:]
    with np.load(out / "memory.npz") as data:
        learned = int(data["trials_learned"])
    # the memory is that of the last finished trial (or, if the signal fell between the two
    # writes, the one before: going on from it repeats that trial, losing nothing)
    assert learned in (len(rows), len(rows) - 1)
    assert f"--init-memory {out}/memory.npz --first-trial {learned} " in err
    # going on from it gives what one uninterrupted run gives
    cont, full = tmp_path / "cont", tmp_path / "full"
    assert main(["simulate", *args, "--init-memory", str(out / "memory.npz"), "--first-trial",
                 str(learned), "--trials", "2", "--out", str(cont)]) == 0
    assert main(["simulate", *args, "--trials", str(learned + 2), "--out", str(full)]) == 0
    full_rows = (full / "metrics.csv").read_text().splitlines()[1:]
    assert rows[:learned] + (cont / "metrics.csv").read_text().splitlines()[1:] == full_rows


def test_memory_keeper_writes_at_most_every_interval(tmp_path, monkeypatch):
    sc = load_scenario("paper-triangle3")
    now = [100.0]
    monkeypatch.setattr(time, "monotonic", lambda: now[0])
    keeper = MemoryKeeper(tmp_path / "memory.npz", sc, None, 0, interval=2.0)
    mem = np.ones((sc.n, sc.samples, 2))
    keeper.update(1, mem)
    assert not (tmp_path / "memory.npz").exists()  # not yet 2 s
    now[0] += 2.5
    keeper.update(2, 2 * mem)
    np.testing.assert_array_equal(load_memory(tmp_path / "memory.npz", sc), 2 * mem)
    keeper.update(3, 3 * mem)  # within 2 s of the last write: kept, not written
    np.testing.assert_array_equal(load_memory(tmp_path / "memory.npz", sc), 2 * mem)
    keeper.save()
    np.testing.assert_array_equal(load_memory(tmp_path / "memory.npz", sc), 3 * mem)
    assert keeper.writes == 2 and [p.name for p in tmp_path.iterdir()] == ["memory.npz"]


# --------------------------------------------------------------------------- memory files

def _header_bytes(header: dict[str, object]) -> bytes:
    import io

    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, header)
    return buf.getvalue()


def test_a_memory_file_claiming_terabytes_is_refused_from_its_header(tmp_path):
    sc = load_scenario("paper-triangle3")
    good = save_memory(tmp_path / "good.npz", np.zeros((sc.n, sc.samples, 2)), sc)
    bomb = tmp_path / "bomb.npz"
    with zipfile.ZipFile(good) as src, zipfile.ZipFile(bomb, "w") as dst:
        for name in src.namelist():
            if name != "memory.npy":
                dst.writestr(name, src.read(name))
        # a header for 3 x 10^12 x 2 floats (48 TB) and no data
        dst.writestr("memory.npy", _header_bytes({"descr": "<f8", "fortran_order": False,
                                                  "shape": (3, 10 ** 12, 2)}))
    with pytest.raises(MemoryFileError, match=r"bomb\.npz: memory has shape \(3, "
                                              r"1000000000000, 2\), paper-triangle3 needs "
                                              r"\(3, 140, 2\)"):
        load_memory(bomb, sc)
    np.save(tmp_path / "old.npy", np.zeros((3, 10, 2)))
    with pytest.raises(MemoryFileError, match=r"old\.npy: memory has shape \(3, 10, 2\)"):
        load_memory(tmp_path / "old.npy", sc)
    with pytest.raises(ValueError, match="inf or nan"):
        save_memory(tmp_path / "nan.npz", np.full((sc.n, sc.samples, 2), np.nan), sc)


# --------------------------------------------------------------------------- the fuzz test

hypothesis = pytest.importorskip("hypothesis", reason="hypothesis is in the dev extra")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

# a loaded 2-core machine: a slow example is a few seconds, not a hang
settings.register_profile("ci", max_examples=60, deadline=5000, derandomize=True,
                          database=None, suppress_health_check=[HealthCheck.too_slow,
                                                 HealthCheck.function_scoped_fixture])
settings.register_profile("fuzz", max_examples=2000, deadline=10000,
                          suppress_health_check=[HealthCheck.function_scoped_fixture])
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

BASES = [yaml.safe_load(TRIANGLE), yaml.safe_load(load_scenario("paper-hexagon6").text)]

EXTREME_NUMBERS = st.sampled_from([0, 1, 2, 3, -1, 0.0, -0.0, 1e-320, 5e-324, 1e308, -1e308,
                                   float("inf"), float("-inf"), float("nan"), 2 ** 31,
                                   2 ** 63, 10 ** 30, 10 ** 400, 1000000, 0.5, 1e-9])
HOSTILE = st.recursive(
    st.one_of(st.none(), st.booleans(), EXTREME_NUMBERS, st.floats(), st.integers(),
              st.text(max_size=20), st.sampled_from(["0.05 deg", "nan deg", "1e999 deg",
                                                     "paper-ivb", "paper", "world", "leader",
                                                     "x" * 5000])),
    lambda inner: st.one_of(st.lists(inner, max_size=5),
                            st.dictionaries(st.one_of(st.text(max_size=8), st.integers(-2, 8)),
                                            inner, max_size=5)),
    max_leaves=20)


def _paths(node: object, prefix: tuple[object, ...] = ()) -> list[tuple[object, ...]]:
    out = [prefix]
    if isinstance(node, dict):
        for k, v in node.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out += _paths(v, prefix + (i,))
    return out


@st.composite
def mutated(draw: st.DrawFn) -> str:
    """A built-in scenario with one to three fields replaced, deleted, nested deeply, or
    joined by an unknown key."""
    import copy

    doc = copy.deepcopy(draw(st.sampled_from(BASES)))
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(_paths(doc)[1:]))
        parent = doc
        for key in path[:-1]:
            parent = parent[key]
        action = draw(st.sampled_from(["replace", "replace", "delete", "nest", "unknown"]))
        if action == "replace":
            parent[path[-1]] = draw(HOSTILE)
        elif action == "delete":
            del parent[path[-1]]
        elif action == "nest":
            value = parent[path[-1]]
            for _ in range(draw(st.integers(1, 60))):
                value = [value]
            parent[path[-1]] = value
        elif isinstance(parent, dict):
            parent[draw(st.text(min_size=1, max_size=8))] = draw(HOSTILE)
    return yaml.safe_dump(doc, sort_keys=False, allow_unicode=True)


def _property(make: object) -> None:
    """Loads to a scenario whose desired trajectories are finite, or fails with one line
    'fuzz.yaml: <field>: <why>'."""
    try:
        sc = make()  # type: ignore[operator]
        assert np.isfinite(sc.reference).all()
        if sc.n * sc.samples <= 20_000:
            d = sc.desired
            assert np.isfinite(d.eta).all() and np.isfinite(d.u).all()
    except ScenarioError as exc:
        msg = str(exc)
        assert msg.startswith("fuzz.yaml: "), msg
        assert "\n" not in msg and len(msg) < 600, msg
        assert msg.count(": ") >= 2, msg  # file: field: why


@given(mutated())
def test_fuzz_loader_on_mutated_scenarios(little_memory, text):
    _property(lambda: scenario_from_text(text, "fuzz.yaml"))


@given(st.one_of(st.text(max_size=300),
                 st.binary(max_size=300).map(lambda b: b.decode("latin-1")),
                 st.builds(lambda depth: "[" * depth + "]" * depth, st.integers(0, 5000))))
def test_fuzz_loader_on_arbitrary_text(little_memory, text):
    _property(lambda: scenario_from_text(text, "fuzz.yaml"))


@settings(max_examples=30)
@given(st.binary(max_size=2000))
def test_fuzz_loader_on_random_bytes(tmp_path_factory, little_memory, data):
    p = tmp_path_factory.mktemp("fuzz") / "fuzz.yaml"
    p.write_bytes(data)
    try:
        load_scenario(p)
    except ScenarioError as exc:
        msg = str(exc)
        assert msg.startswith(f"{p}: ") and "\n" not in msg, msg


@pytest.mark.parametrize("levels", [33, 999, 1000, 5000])
def test_deep_flow_nesting_gets_the_loaders_message_whatever_libyaml_allows(levels):
    # libyaml (PyYAML >= 6.0.4) refuses 1000 flow levels with a message of its own while
    # it scans ahead; the loader's bound is applied before it gets there
    deep = "dt: 0.1\nname: " + "[" * levels + "]" * levels + "\n"
    with pytest.raises(ScenarioError, match=rf"^d\.yaml: line 2: name[\[\]0]+\.\.\.: nested "
                                            rf"deeper than {MAX_YAML_DEPTH} levels; refused$"):
        scenario_from_text(deep, "d.yaml")


def test_brackets_in_quotes_comments_and_words_do_not_count_as_nesting():
    from formation_ilc.config.yamlfields import deep_flow_end

    many = "[" * 40
    assert deep_flow_end(f"description: '{many}'\n") is None
    assert deep_flow_end(f'description: "\\"{many}"\n') is None  # an escaped quote
    assert deep_flow_end(f"dt: 0.1  # {many}\n") is None
    # an apostrophe inside a word starts no quoted scalar: the brackets after it count
    assert deep_flow_end(f"description: don't\nname: {many}\n") is not None
    # brackets inside a plain scalar do count (an upper bound), and the events then decide:
    # a plain scalar is accepted as what it is
    from formation_ilc.config.scenario import parse_yaml

    text = f"description: a{many}\n"
    assert deep_flow_end(text) is not None
    assert parse_yaml(text, "p.yaml") == {"description": f"a{many}"}
