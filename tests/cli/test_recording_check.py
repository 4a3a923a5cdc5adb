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
