"""At the end of a recorded run the launcher reads the recording back (every part, as
``analyze`` does): a run whose recording lacks a trial has not succeeded (status 3, the
trials named); before, a recorder and a robot killed a moment apart lost a whole trial and
the launcher exited 0."""

from __future__ import annotations

import pytest

pytest.importorskip("mcap")
pytest.importorskip("rclpy")

import msgs_schema as ms  # noqa: E402
from formation_ilc.cli.launch import INCOMPLETE, check_recording  # noqa: E402
from formation_ilc.config.runconfig import RunConfig  # noqa: E402
from formation_ilc.config.scenario import load_scenario  # noqa: E402
from formation_ilc.model.simulate import simulate  # noqa: E402
from formation_ilc.recordings import cdr  # noqa: E402
from formation_ilc.recordings.mcap_io import RosMcapWriter, read_messages  # noqa: E402
from formation_ilc.recordings.recording import SimRecorder, load_recording  # noqa: E402


def record(path, trials: int):
    sc = load_scenario("paper-triangle3").with_options(trials=trials)
    rec = SimRecorder(path, sc, ms.recorder_table(sc.n))
    simulate(sc, trials=trials, on_trial_data=rec.trial)
    rec.close()
    return path


def test_a_whole_recording_passes_and_one_without_a_trial_is_status_3(tmp_path, capsys):
    whole = record(tmp_path / "whole.mcap", 4)
    assert check_recording(whole, 4) == 0
    clock = RunConfig.from_json(load_recording(whole).config).clock
    root = tmp_path / "run.mcap"
    with RosMcapWriter(root, flush_period=0) as w:  # trial 1's trajectories never arrived
        for m in read_messages(whole):
            if m.topic.endswith("trajectory") and \
                    clock.decode(int(cdr.decode_path(m.data)[1][0]))[0] == 1:
                continue
            w.channel(m.topic, m.schema, "")
            w.write(m.topic, m.data, m.log_time, m.publish_time)
    capsys.readouterr()
    assert check_recording(root, 4) == INCOMPLETE == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(
        "error: the run finished, but its recording lacks 1 of its 4 trials (1) in run.mcap")
    # a recording never written: every trial is missing
    assert check_recording(tmp_path / "none.mcap", 4) == 3
    assert "none.mcap (never written)" in capsys.readouterr().err


def test_a_resumed_run_whose_missing_trial_was_learned_before_it_is_whole_and_says_why(
        tmp_path, capsys):
    """Reported: a resumed run whose first trial ended 0.05 s before the launcher was
    killed exited 3: that trial's trajectories reached no recorder, though its metrics row
    is right. Now the resumed launch says exactly why, and exits 0 when metrics.csv has
    every trial and every row the recording has equals it; otherwise status 3 as before."""
    from formation_ilc.core.metrics import MetricsWriter

    whole = record(tmp_path / "whole.mcap", 4)
    ref = load_recording(whole).metrics
    clock = RunConfig.from_json(load_recording(whole).config).clock
    root = tmp_path / "run.mcap"
    with RosMcapWriter(root, flush_period=0) as w:
        for m in read_messages(whole):
            if m.topic.endswith("trajectory") and \
                    clock.decode(int(cdr.decode_path(m.data)[1][0]))[0] == 1:
                continue
            w.channel(m.topic, m.schema, "")
            w.write(m.topic, m.data, m.log_time, m.publish_time)

    def metrics(rows) -> object:
        path = tmp_path / "metrics.csv"
        path.unlink(missing_ok=True)
        out = MetricsWriter(path)
        for r in rows:
            out.write(r)
        out.close()
        return path

    path = metrics(ref)
    capsys.readouterr()
    assert check_recording(root, 4, resumed_at=2, metrics=path) == 0
    out = capsys.readouterr().out
    assert "lacks trial 1: learned before this launch resumed the run (at 2 trials)" in out
    assert "the recording's 3 others equal metrics.csv to the last bit" in out
    # learned in this launch: not explained by the resume
    assert check_recording(root, 4, resumed_at=1, metrics=path) == INCOMPLETE
    # metrics.csv without the row, or with a row the recording contradicts
    assert check_recording(root, 4, resumed_at=2, metrics=metrics(ref[[0, 2, 3]])) == 3
    wrong = ref.copy()
    wrong[2, 1] += 1e-12
    assert check_recording(root, 4, resumed_at=2, metrics=metrics(wrong)) == 3
    assert check_recording(root, 4) == 3  # not a resumed run
