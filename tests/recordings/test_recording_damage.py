"""Recordings that are damaged, cut short or hold junk: ``read_messages`` resynchronises on
the next valid record and says what it lost; ``load_recording`` and ``analyze`` skip and
count what does not decode, recover every trial whose data reads back, and say which are
incomplete; a writer killed with SIGKILL leaves a file that reads back up to its last
flushed chunk."""

from __future__ import annotations

import random
import signal
import subprocess
import sys
import textwrap
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mcap")
pytest.importorskip("rclpy")
from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

import msgs_schema as ms  # noqa: E402
from formation_ilc.cli import main  # noqa: E402
from formation_ilc.config.runconfig import RunConfig  # noqa: E402
from formation_ilc.config.scenario import load_scenario  # noqa: E402
from formation_ilc.model.simulate import simulate  # noqa: E402
from formation_ilc.protocol.health import flatten  # noqa: E402
from formation_ilc.recordings import cdr  # noqa: E402
from formation_ilc.recordings.mcap_io import (  # noqa: E402
    ReadReport,
    RosMcapWriter,
    read_messages,
)
from formation_ilc.recordings.recording import (  # noqa: E402
    SimRecorder,
    load_recording,
    recording_parts,
    root_of,
)

SCENARIO = "paper-triangle3"


def record(path: Path, trials: int, extra=None) -> Path:
    """A batch run recorded as the stack's recorder would (``extra(rec)`` adds messages)."""
    sc = load_scenario(SCENARIO).with_options(trials=trials)  # as `simulate --trials` records
    rec = SimRecorder(path, sc, ms.recorder_table(sc.n))
    simulate(sc, trials=trials, on_trial_data=rec.trial)
    if extra is not None:
        extra(rec)
    rec.close()
    return path


@pytest.fixture(scope="module")
def run40(tmp_path_factory) -> tuple[Path, np.ndarray]:
    """40 trials recorded, and the metrics that read back from the intact file."""
    path = record(tmp_path_factory.mktemp("rec") / "run.mcap", 40)
    return path, load_recording(path).metrics


def chunks_of(path: Path) -> list[tuple[int, int, Counter]]:
    """(offset, length, messages by (topic, data)) of each chunk of an intact file."""
    from io import BytesIO

    from mcap.data_stream import ReadDataStream
    from mcap.reader import make_reader
    from mcap.records import Chunk, Message
    from mcap.stream_reader import breakup_chunk

    data = path.read_bytes()
    with path.open("rb") as fh:
        summary = make_reader(fh).get_summary()
    topics = {c.id: c.topic for c in summary.channels.values()}
    out = []
    for ci in summary.chunk_indexes:
        body = data[ci.chunk_start_offset + 9: ci.chunk_start_offset + ci.chunk_length]
        chunk = Chunk.read(ReadDataStream(BytesIO(body)))
        msgs = Counter((topics[r.channel_id], bytes(r.data))
                       for r in breakup_chunk(chunk) if isinstance(r, Message))
        out.append((ci.chunk_start_offset, ci.chunk_length, msgs))
    return out


def corrupt(src: Path, dst: Path, at: int, size: int = 64, seed: int = 1) -> None:
    b = bytearray(src.read_bytes())
    rng = random.Random(seed)
    for i in range(at, min(at + size, len(b))):
        b[i] = rng.randrange(256)
    dst.write_bytes(bytes(b))


# --------------------------------------------------------------------------- junk inside

def test_junk_messages_are_skipped_and_counted_not_fatal(tmp_path, capsys):
    """Reported: one junk message on /formation/diagnostics made analyze fail with a
    traceback. Junk of every analysed kind is now skipped and counted per topic."""
    def junk(rec: SimRecorder) -> None:
        t = 10**12
        rec.w.write(rec.full[ms.DIAGNOSTICS], cdr.encode_string("{junk"), t, t)
        rec.w.write(rec.full[ms.DIAGNOSTICS], cdr.encode_diagnostic_array(t, [
            (0, "robot_1", "", "", flatten({"node": "robot_1", "trial": 0,
                                            "delays": {"leader": {"x": "y"}}}))]), t, t)
        rec.w.write(rec.full[ms.TRIAL_EVENTS], cdr.encode_string("[1, 2"), t, t)
        rec.w.write(rec.full[ms.TRIAL_EVENTS], b"\x00\x01\x00\x00\xff\xff", t, t)
        pb = rec.pb
        k = rec.sc.trials + 5
        stamps = np.array([rec.clock.stamp_ns(k, s) for s in range(pb.samples + 1)])
        # a trajectory of a trial the run never had, and one that is not one
        rec.w.write(rec.full[ms.trajectory_topic(1)],
                    cdr.encode_path(pb.eta_d[0], stamps, ms.WORLD_FRAME, 0), t, t)
        rec.w.write(rec.full[ms.trajectory_topic(2)], b"\x00\x01\x00\x00" + b"\xff" * 40,
                    t, t)

    path = record(tmp_path / "junk.mcap", 3, junk)
    ref = simulate(load_scenario(SCENARIO), trials=3).metrics
    r = load_recording(path)
    np.testing.assert_allclose(r.metrics, ref, rtol=1e-13, atol=1e-13)
    assert r.undecodable == {"/formation/diagnostics": 2, "/formation/leader/trial_events": 2,
                             "/formation/robot_1/trajectory": 1,
                             "/formation/robot_2/trajectory": 1}
    assert r.delays["robot_1->robot_2"]  # the valid diagnostics still count
    assert not r.report.damaged and r.incomplete == []
    assert main(["analyze", str(path), "--out", str(tmp_path / "an"), "--no-plots"]) == 0
    out = capsys.readouterr().out
    assert "skipped messages that do not decode: /formation/diagnostics 2" in out


def test_a_file_with_no_run_configuration_is_one_error_line(tmp_path, capsys):
    bad = tmp_path / "noise.mcap"
    bad.write_bytes(random.Random(0).randbytes(5000))
    assert main(["analyze", str(bad), "--out", str(tmp_path / "an")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no readable run configuration" in err[0]


# --------------------------------------------------------------------------- damage

def test_64_corrupted_bytes_lose_one_chunk_and_say_so(run40, tmp_path, capsys):
    """Reported: 64 corrupted bytes in the middle made analyze report 5 of 40 trials with
    no warning. Now every chunk after the damage is read, the lost chunk is named with its
    messages, the trials it held are listed, and analyze exits 1."""
    path, ref = run40
    bad = tmp_path / "bad.mcap"
    size = path.stat().st_size
    corrupt(path, bad, size // 2)
    rep = ReadReport()
    msgs = list(read_messages(bad, report=rep))
    intact = list(read_messages(path))
    lost_chunks = [c for c in chunks_of(path) if c[0] < size // 2 + 64
                   and size // 2 < c[0] + c[1]]
    assert len(lost_chunks) == 1
    lost = lost_chunks[0][2]
    # exactly the damaged chunk's messages are missing, everything else reads back
    assert Counter((m.topic, bytes(m.data)) for m in msgs) == \
        Counter((m.topic, bytes(m.data)) for m in intact) - lost
    assert rep.damaged and len(rep.damage) == 1
    d = rep.damage[0]
    assert d.start <= size // 2 < d.end and d.chunks == 1
    assert rep.lost_messages == sum(lost.values()) == len(intact) - len(msgs)
    r = load_recording(bad)
    kept = [k for k in range(40) if k not in r.incomplete]
    assert 1 <= len(r.incomplete) <= 2 and len(r.metrics) == len(kept) == 40 - len(r.incomplete)
    np.testing.assert_array_equal(r.metrics, ref[kept])
    assert main(["analyze", str(bad), "--out", str(tmp_path / "an"), "--no-plots"]) == 1
    err = capsys.readouterr().err
    assert "damaged recording" in err and f"{rep.lost_messages} lost" in err
    assert f"trial(s) {', '.join(map(str, r.incomplete))} not complete" in err


def test_losing_the_chunk_that_defined_the_channels_orphans_nothing(run40, tmp_path):
    """Every schema and channel is written a second time outside its chunk: the messages
    of later chunks keep their topics when the first chunk is lost."""
    path, _ = run40
    first = chunks_of(path)[0]
    bad = tmp_path / "bad.mcap"
    corrupt(path, bad, first[0] + first[1] // 2)
    rep = ReadReport()
    got = Counter((m.topic, bytes(m.data)) for m in read_messages(bad, report=rep))
    whole = Counter((m.topic, bytes(m.data)) for m in read_messages(path))
    assert rep.orphans == 0 and got == whole - first[2]


def test_damage_in_a_file_cut_short_is_read_past_and_counted(run40, tmp_path):
    """No summary to consult (a killed recorder): the lost chunk's own message index, which
    follows it, still says how many messages it held."""
    path, ref = run40
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.8)])
    bad = tmp_path / "cut-bad.mcap"
    corrupt(cut, bad, len(data) // 3)
    rep = ReadReport()
    n = sum(1 for _ in read_messages(bad, report=rep))
    n_cut = sum(1 for _ in read_messages(cut))
    assert rep.cut_short and len(rep.damage) == 1 and rep.total_messages is None
    assert rep.damage[0].messages == n_cut - n > 0
    r = load_recording(bad)
    assert len(r.metrics) >= 25  # about 80 % of 40 trials, minus the lost chunk's
    np.testing.assert_array_equal(r.metrics, ref[r.metrics[:, 0].astype(int)])


@settings(max_examples=25, deadline=None, database=None)
@given(data=st.data())
def test_any_damage_loses_only_the_chunks_it_hits(tmp_path_factory, data):
    """Random corruption (a burst anywhere, or scattered bytes): reading never fails, and
    every chunk the damage did not touch reads back whole."""
    base = tmp_path_factory.getbasetemp() / "small.mcap"
    if not base.exists():
        record(base, 4)
    size = base.stat().st_size
    b = bytearray(base.read_bytes())
    hit: list[int] = []
    for _ in range(data.draw(st.integers(1, 3))):
        at = data.draw(st.integers(0, size - 1))
        n = data.draw(st.sampled_from([1, 8, 64, 700]))
        rng = random.Random(at)
        for i in range(at, min(at + n, size)):
            b[i] ^= rng.randrange(1, 256)  # every byte of the burst changes
            hit.append(i)
    bad = tmp_path_factory.getbasetemp() / "small-bad.mcap"
    bad.write_bytes(bytes(b))
    rep = ReadReport()
    got = Counter((m.topic, bytes(m.data)) for m in read_messages(bad, report=rep))
    whole = Counter((m.topic, bytes(m.data)) for m in read_messages(base))
    assert not got - whole  # nothing read back that was not written
    for off, length, msgs in chunks_of(base):
        if not any(off <= i < off + length for i in hit):
            assert not msgs - got, f"untouched chunk at {off} lost messages"
    if sum(got.values()) < sum(whole.values()):
        assert rep.damaged or rep.cut_short


# --------------------------------------------------------------------------- SIGKILL

_WRITER = textwrap.dedent("""
    import sys, time
    from formation_ilc.recordings.mcap_io import RosMcapWriter
    from formation_ilc.recordings.recording import qos_of
    import msgs_schema as ms
    from formation_ilc.recordings import cdr
    w = RosMcapWriter(sys.argv[1], flush_period=0)
    w.channel("/formation/robot_1/pose", "geometry_msgs/msg/PoseStamped", qos_of(ms.SAMPLE_QOS))
    i = 0
    while True:
        for _ in range(500):
            w.write("/formation/robot_1/pose", cdr.encode_pose_stamped((i, 0.0, 0.0), i, "map"),
                    i, i)
            i += 1
        w.flush()
        print(i, flush=True)
""")


def test_a_writer_killed_with_sigkill_loses_only_its_last_chunk(tmp_path):
    """What the recorder relies on: a SIGKILL at any moment leaves a file that reads back,
    without damage, every message flushed before it (the chunk in progress is all that is
    lost)."""
    path = tmp_path / "killed.mcap"
    proc = subprocess.Popen([sys.executable, "-c", _WRITER, str(path)],
                            stdout=subprocess.PIPE, text=True)
    try:
        flushed = 0
        while flushed < 20000:
            line = proc.stdout.readline()
            assert line, "the writer died"
            flushed = int(line)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    rep = ReadReport()
    xs = [m.publish_time for m in read_messages(path, report=rep)]
    assert rep.cut_short and not rep.damaged
    assert len(xs) >= flushed
    assert xs == list(range(len(xs)))  # every message up to the last flush, in order


# --------------------------------------------------------------------------- a run not whole

def test_a_recording_without_a_trial_of_its_run_exits_3_naming_it(tmp_path, capsys):
    """An intact file that lacks trials of its run (a recorder and a robot killed a moment
    apart lost a whole trial; a run interrupted before its end) is not a whole run: the
    analysis writes what there is, names the trials and exits non-zero."""
    whole = record(tmp_path / "whole.mcap", 5)
    clock = RunConfig.from_json(load_recording(whole).config).clock
    cut = tmp_path / "cut.mcap"
    with RosMcapWriter(cut, flush_period=0) as w:
        for m in read_messages(whole):
            if m.topic.endswith("trajectory") and \
                    clock.decode(int(cdr.decode_path(m.data)[1][0]))[0] == 2:
                continue  # trial 2's trajectories never reached the file
            w.channel(m.topic, m.schema, "")
            w.write(m.topic, m.data, m.log_time, m.publish_time)
    r = load_recording(cut)
    assert r.missing == [2] and r.incomplete == [2] and not r.report.damaged
    assert main(["analyze", str(cut), "--out", str(tmp_path / "an"), "--no-plots"]) == 3
    err = capsys.readouterr().err
    assert "the run is not whole: 1 of its 5 trials are not complete in the file (trial 2)" \
        in err
    assert load_recording(whole).missing == []
    assert main(["analyze", str(whole), "--out", str(tmp_path / "an2"), "--no-plots"]) == 0


def test_a_run_resumed_before_its_first_recording_existed_reads_as_one_run(tmp_path, capsys):
    """RUN.mcap was never written; RUN.resumed1.mcap holds the later trials. analyze RUN.mcap
    reads the parts that exist, and the missing first trials make it exit 3; a part given
    alone says which run it belongs to."""
    first = record(tmp_path / "a.mcap", 5)
    part = tmp_path / "run.resumed1.mcap"
    first.rename(part)
    root = tmp_path / "run.mcap"
    assert recording_parts(root) == [part]
    assert root_of(part) == root and root_of(tmp_path / "run.resumed1.part2.mcap") == root
    assert main(["analyze", str(root), "--out", str(tmp_path / "an"), "--no-plots"]) == 0
    assert "run.mcap does not exist; the run's files are run.resumed1.mcap" in \
        capsys.readouterr().err
    assert main(["analyze", str(part), "--out", str(tmp_path / "an2"), "--no-plots"]) == 0
    assert "run.resumed1.mcap is one part of the run recorded in run.mcap" in \
        capsys.readouterr().err


def test_the_leaders_repeated_start_reads_as_one_event(tmp_path):
    """The leader repeats a start while its slot does not move (same seq): a recording
    lists it once among the run's events, and its trials read as before."""
    def repeats(rec: SimRecorder) -> None:
        t = rec.clock.stamp_ns(2, rec.pb.samples) + 1
        for _ in range(3):
            rec._json(ms.TRIAL_EVENTS, {"event": "start", "trial": 2, "slot": 2, "seq": 5}, t)

    r = load_recording(record(tmp_path / "repeats.mcap", 3, repeats))
    assert [e.get("seq") for e in r.events if e["event"] == "start"] == [None, None, None, 5]
    np.testing.assert_allclose(r.metrics, simulate(load_scenario(SCENARIO), trials=3).metrics,
                               rtol=1e-13, atol=1e-13)
    assert r.incomplete == []


# --------------------------------------------------------------------------- no single point

def trials_in(msgs: Counter, clock) -> set[int]:
    """The trials whose trajectories are among ``msgs`` ((topic, data) of a chunk)."""
    return {clock.decode(int(cdr.decode_path(data)[1][0]))[0]
            for (topic, data) in msgs if topic.endswith("trajectory")}


def test_any_64_bytes_of_the_first_chunk_overwritten_keep_every_other_trial(run40, tmp_path,
                                                                           capsys):
    """Reported: 16-64 damaged bytes at the start of a recording made analyze exit 2 with
    0 trials: the one message lost was the run configuration, stored once. Now the
    configuration (and the run key) is also in a metadata record written before the first
    chunk, again after it and at the end, and in its channel's metadata (outside the
    chunks, and in the summary): whichever 64 bytes of the first chunk (or of what comes
    before it) are overwritten, every trial the rest of the file holds is analysed, equal
    to the intact file's rows, and analyze says what was lost (exit 1)."""
    path, ref = run40
    first = chunks_of(path)[0]
    clock = RunConfig.from_json(load_recording(path).config).clock
    lost = trials_in(first[2], clock)
    assert any(t.endswith("/config") for t, _ in first[2])  # the message is in it
    end = first[0] + first[1]
    for at in sorted({0, 8, first[0] - 32, first[0], first[0] + 9, first[0] + 40,
                      *range(first[0] + 64, end - 64, max(64, (end - first[0]) // 12)),
                      end - 64}):
        bad = tmp_path / f"bad{at}.mcap"
        corrupt(path, bad, max(0, at), seed=at)
        r = load_recording(bad)
        got = set(r.metrics[:, 0].astype(int).tolist())
        assert got >= set(range(40)) - lost, (at, sorted(set(range(40)) - got))
        np.testing.assert_array_equal(r.metrics, ref[sorted(got)])
        assert r.report.damaged
    assert main(["analyze", str(bad), "--out", str(tmp_path / "an"), "--no-plots"]) == 1
    capsys.readouterr()


def test_mcap_repair_puts_the_lost_configuration_back_and_refuses_junk(run40, tmp_path,
                                                                      capsys):
    """The first chunk (with the configuration's message) lost: the repaired copy has the
    message again, rebuilt from its copy in the file's metadata, and reads as a recording
    (without the metadata, from the run's folder). Junk: exit 2, one line, nothing
    written (before: exit 0 and an empty file)."""
    path, ref = run40
    first = chunks_of(path)[0]
    bad = tmp_path / "bad.mcap"
    corrupt(path, bad, first[0] + first[1] // 2)
    fixed = tmp_path / "fixed.mcap"
    assert main(["mcap-repair", str(bad), "-o", str(fixed)]) == 0
    out = capsys.readouterr().out
    assert "the run configuration's message on /formation/config was lost: rebuilt from " \
           "its copy in the file's metadata" in out
    topics = Counter(m.topic for m in read_messages(fixed))
    assert topics["/formation/config"] == 1
    r = load_recording(fixed)
    assert r.notes == [] and len(r.metrics) >= 37  # from the message, no note
    np.testing.assert_array_equal(r.metrics, ref[r.metrics[:, 0].astype(int)])
    # junk
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(random.Random(3).randbytes(3000))
    out_file = tmp_path / "j.mcap"
    assert main(["mcap-repair", str(junk), "-o", str(out_file)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {junk}: no MCAP record reads back")
    assert not out_file.exists() and not list(tmp_path.glob(".j.mcap*"))


def test_a_recording_without_any_copy_of_its_configuration_is_rebuilt_from_the_run_folder(
        tmp_path, capsys):
    """Every copy lost (here: a file written with none but the trials): analyze refuses it
    in one line that says where a copy is; with the run's folder (config.json, as the
    launcher writes it) it analyses the file, checking the run id."""
    import json

    from formation_ilc.protocol import wire

    whole = record(tmp_path / "whole.mcap", 4)
    conf = load_recording(whole).config
    run = tmp_path / "run"
    run.mkdir()
    bare = run / "run.mcap"
    with RosMcapWriter(bare, flush_period=0) as w:
        for m in read_messages(whole):
            if m.topic.endswith("/config"):
                continue
            w.channel(m.topic, m.schema, "")
            w.write(m.topic, m.data, m.log_time, m.publish_time)
    assert main(["analyze", str(bare), "--out", str(tmp_path / "an"), "--no-plots"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no readable run configuration" in err[0] and "--run-dir" in err[0]
    (run / "config.json").write_text(json.dumps(conf))
    assert main(["analyze", str(bare), "--out", str(tmp_path / "an2"), "--no-plots"]) == 0
    assert "taken from the run's folder (config.json)" in capsys.readouterr().out
    r = load_recording(bare, fallback=conf)
    np.testing.assert_allclose(r.metrics, load_recording(whole).metrics, rtol=0, atol=0)
    fixed = tmp_path / "fixed.mcap"
    assert main(["mcap-repair", str(bare), "-o", str(fixed), "--run-dir", str(run)]) == 0
    assert "rebuilt from the run's folder (config.json)" in capsys.readouterr().out
    assert len(load_recording(fixed).metrics) == 4
    # another run's folder is refused, naming both runs (the events carry the run id)
    other = tmp_path / "other"
    other.mkdir()
    (other / "config.json").write_text(json.dumps(conf | {"run_id": "rsomeoneelse"}))
    with_run = run / "events.mcap"
    with RosMcapWriter(with_run, flush_period=0) as w:
        for m in read_messages(bare):
            data = m.data
            if m.topic.endswith("/trial_events"):
                d = json.loads(wire.read_string(data)) | {"run": conf.get("run_id") or "r1"}
                data = cdr.encode_string(json.dumps(d))
            w.channel(m.topic, m.schema, "")
            w.write(m.topic, data, m.log_time, m.publish_time)
    assert main(["analyze", str(with_run), "--out", str(tmp_path / "an3"), "--no-plots",
                 "--run-dir", str(other)]) == 2
    assert "the run folder's configuration is of run rsomeoneelse" in capsys.readouterr().err
    # and so does mcap-repair (it took any folder's configuration before), writing nothing
    fixed2 = tmp_path / "fixed2.mcap"
    assert main(["mcap-repair", str(with_run), "-o", str(fixed2), "--run-dir",
                 str(other)]) == 2
    err = capsys.readouterr().err
    assert "the run folder's configuration is of run rsomeoneelse" in err, err
    assert not fixed2.exists() and not list(tmp_path.glob(".fixed2*"))
    same = tmp_path / "same"
    same.mkdir()
    (same / "config.json").write_text(json.dumps(conf | {"run_id": conf.get("run_id")
                                                          or "r1"}))
    assert main(["mcap-repair", str(with_run), "-o", str(fixed2), "--run-dir",
                 str(same)]) == 0
    assert len(load_recording(fixed2).metrics) == 4
