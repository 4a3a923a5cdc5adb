"""Liveness and honest outcomes of the real stack: a forged abort and a forged "down" are
recovered from (the run finishes equal to batch), a run waiting for a node that never comes
stops within its bound naming it (status 4, with the resume command), a full disk stops the
run with one line naming the file and the resume command (status 5, no restarts)."""

from __future__ import annotations

import json
import os
import shutil
import stat
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

import msgs_schema as ms
from formation_ilc.config.scenario import load_scenario
from formation_ilc.core.metrics import read_metrics
from formation_ilc.model.simulate import simulate

from ..procs import end_forger, stop_group

pytestmark = [pytest.mark.ros, pytest.mark.multiprocess]

TOL = 1e-9
TRIALS = 7
SEED = 5


def launch(env: dict[str, str], out: Path, *args: str, prefix: list[str] | None = None
           ) -> subprocess.Popen[str]:
    argv = [*(prefix or []), sys.executable, "-m", "formation_ilc.cli", "launch", *args,
            "--out", str(out), "--domain-id", env["ROS_DOMAIN_ID"], "--no-plots",
            "--timeout", "20"]
    return subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True)


class Peer:
    """A node of the test's own, outside the formation's namespace (``/NAME``), spun by the
    test."""

    def __init__(self, context, name: str):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.node = rclpy.create_node(name, namespace=f"/{name}", context=context)
        self.ex = SingleThreadedExecutor(context=context)
        self.ex.add_node(self.node)

    def spin(self) -> None:
        self.ex.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        self.ex.shutdown()
        self.node.destroy_node()


class Forger(Peer):
    """A peer that watches the formation's configuration, events and readies, and
    publishes what a hostile peer would."""

    def __init__(self, context):
        from std_msgs.msg import String

        super().__init__(context, "forger")
        topic = lambda t: ms.absolute(t, ms.NAMESPACE)  # noqa: E731
        self.run_id = ""
        self.starts: list[dict] = []
        self.boots: dict[str, str] = {}
        self.node.create_subscription(String, topic(ms.CONFIG), self._config, ms.LATCHED_QOS)
        self.node.create_subscription(String, topic(ms.TRIAL_EVENTS), self._event,
                                      ms.SAMPLE_QOS)
        self.node.create_subscription(String, topic(ms.READY), self._ready,
                                      ms.LATCHED_READER_QOS)
        self.events = self.node.create_publisher(String, topic(ms.TRIAL_EVENTS),
                                                 ms.SAMPLE_QOS)
        self.ready = self.node.create_publisher(String, topic(ms.READY), ms.LATCHED_QOS)

    def _config(self, msg) -> None:
        self.run_id = json.loads(msg.data).get("run_id", "")

    def _event(self, msg) -> None:
        d = json.loads(msg.data)
        if d.get("event") == "start" and d.get("run") == self.run_id:
            self.starts.append(d)

    def _ready(self, msg) -> None:
        d = json.loads(msg.data)
        if not d.get("down"):
            self.boots[d["node"]] = d.get("boot", "")

    def publish(self, pub, d: dict) -> None:
        from std_msgs.msg import String

        pub.publish(String(data=json.dumps(d)))


def batch() -> np.ndarray:
    return simulate(load_scenario("paper-triangle3").with_options(seed=SEED),
                    trials=TRIALS).metrics


def key_is_private(rec: Path) -> dict[str, object]:
    """The recording's mode, and (as root) whether uid 65534 could read it, through a
    hard link in a folder anyone may enter (only the file's own mode can refuse it)."""
    out: dict[str, object] = {"mode": stat.S_IMODE(rec.stat().st_mode)}
    if os.geteuid() != 0:
        return out
    pub = Path(tempfile.mkdtemp(prefix="formation-ilc-key-"))
    try:
        pub.chmod(0o755)
        try:
            os.link(rec, pub / rec.name)
        except OSError:  # another file system: the mode alone is checked
            return out

        def drop() -> None:
            os.setgid(65534)
            os.setuid(65534)

        res = subprocess.run(["head", "-c", "1", str(pub / rec.name)], preexec_fn=drop,
                             capture_output=True, text=True, timeout=60, cwd="/")
        out["other_uid"] = ("refused" if res.returncode and "denied" in res.stderr
                            else "read" if res.returncode == 0 else res.stderr[-300:])
    finally:
        shutil.rmtree(pub, ignore_errors=True)
    return out


def test_forged_events_and_a_forged_down_move_nothing(ros_env, context, tmp_path):
    """Six forgeries in one run, each with the run id read from the latched configuration:
    an abort of the running slot and a "down" of the live recorder from a peer in this
    process; a burst of 72 events (starts, aborts, ends, a done) the moment trial 2 ends,
    and an abort of the slot trial 4 ran once every robot has learned it (with the seq the
    leader gives its next start), a ready in robot_1's name with another seed (from a node
    of its own, and from a node it names robot_1 in the formation's namespace) and reports
    in the plant's name (a contact slot that is text, a line of terminal escapes, contacts
    in a run without bodies), from a second process (tests/stack/forger.py).

    Before: the forged abort made the simulator leave its trial and the leader wait for its
    /clock forever; the "down" made the leader wait for a live recorder; the burst filed a
    copy of one trial under the next number and the run ended with exit 0; the abort of the
    committed slot made the leader take the trial back and wait for a rollback that never
    came (status 4). Now no follower takes an event the leader did not seal, the recorder
    refutes the "down": the run finishes equal to batch, with every trial recorded, and the
    recording analyses equal to batch too."""
    rec = tmp_path / "run.mcap"
    proc = launch(ros_env, tmp_path, "paper-triangle3", "--trials", str(TRIALS), "--seed",
                  str(SEED), "--record", str(rec))
    forger = None
    forged: dict[str, dict] = {}
    second = subprocess.Popen([sys.executable, str(Path(__file__).with_name("forger.py")),
                               "--burst-at", "2", "--abort-committed", "4",
                               "--ready-as", "3", "--bad-report", "3",
                               "--impostor", "robot_1"], env=ros_env,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                              start_new_session=True)
    private: dict[str, object] = {}
    try:
        deadline = time.monotonic() + 600
        while proc.poll() is None and time.monotonic() < deadline:
            if forger is None:
                if (tmp_path / "metrics.csv").exists():  # the formation runs: join it
                    forger = Forger(context)
                else:
                    time.sleep(0.1)  # waiting for the launcher, bounded by the deadline
                continue
            forger.spin()
            last = forger.starts[-1] if forger.starts else None
            if last is None or not forger.run_id:
                continue
            if not private and last["trial"] >= 1 and rec.exists():  # the run lives
                private.update(key_is_private(rec))
            # the first running slot it sees from trial 1 on (under load it may join later)
            if "abort" not in forged and last["trial"] >= 1:
                forged["abort"] = {"event": "abort", "trial": last["trial"],
                                   "slot": last["slot"], "seq": last["seq"] + 1,
                                   "why": "forged", "run": forger.run_id}
                forger.publish(forger.events, forged["abort"])
            if "down" not in forged and last["trial"] == 3 and "recorder" in forger.boots:
                forged["down"] = {"node": "recorder", "trial": TRIALS, "passive": True,
                                  "boot": forger.boots["recorder"], "down": True,
                                  "run": forger.run_id}
                forger.publish(forger.ready, forged["down"])
        out, err = proc.communicate(timeout=60)
        said = end_forger(second)
    finally:
        stop_group(proc)
        stop_group(second)
        if forger is not None:
            forger.close()
    assert set(forged) == {"abort", "down"}, forged
    # while the run lived its recording, which holds the events' key, was the user's alone
    # (another uid could not read it); once over, it has the user's umask's modes again
    assert private["mode"] & 0o077 == 0, private
    assert private.get("other_uid", "refused") == "refused", private
    umask = os.umask(0o022)
    os.umask(umask)
    assert rec.stat().st_mode & 0o077 == 0o666 & ~umask & 0o077
    by_second = [json.loads(ln) for ln in said.splitlines() if ln.startswith("{")]
    assert sorted(d["forged"] for d in by_second) == ["abort", "burst", "ready",
                                                      "ready_as_node", "report"], said
    assert [d["count"] for d in by_second if d["forged"] == "burst"] == [72]
    assert proc.returncode == 0, out + err
    got = read_metrics(tmp_path / "metrics.csv")
    np.testing.assert_array_equal(got[:, 0], np.arange(TRIALS))
    np.testing.assert_allclose(got[:, 1:], batch()[:, 1:], rtol=0, atol=TOL)
    diag = json.loads((tmp_path / "diagnostics.json").read_text())
    assert diag["virtual_leader"]["foreign_events"] >= 2  # both aborts, counted, not obeyed
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["restarts"] == {}
    # the monitor refused every forged event, naming the other writer from the graph
    assert summary["foreign_events"]["count"] >= 74, summary["foreign_events"]
    assert "/forger/forger" in summary["foreign_events"]["writers"]
    assert "foreign trial events: " in out
    # the ready in robot_1's name and the reports in the plant's, from another writer:
    # refused by the leader and the monitor, counted by sender, said on the console (the
    # reports' fields would refuse them too: no contact in a run without bodies, a slot
    # that is text); none of their text reached the console. The forger's report writer
    # keeps one message: the monitor may have missed some of the three
    forged = summary["forged"]
    assert forged["virtual_leader"]["/formation/ready"]["/forger/forger"] >= 1, forged
    mon = forged["monitor"]
    assert mon["/formation/ready"]["/forger/forger"] >= 1, forged
    # the node it named robot_1: the graph names its writer as robot_1's, but its
    # participant is not the one robot_1 said ready from (refused once robot_1 spoke again)
    impostor = "/formation/robot_1 (second participant)"
    assert forged["virtual_leader"]["/formation/ready"][impostor] >= 1, forged
    assert mon["/formation/ready"][impostor] >= 1, forged
    assert mon["/formation/diagnostics"]["/forger/forger"] >= 1, forged
    assert "forged: " in out and "\x1b" not in out and "every trial is in" in out
    from formation_ilc.recordings.recording import load_recording, recording_parts

    # the recording holds the forgeries as evidence; its analysis takes the leader's only
    r = load_recording(recording_parts(rec))
    assert r.missing == [] and r.foreign >= 74
    assert not any(e["event"] == "abort" for e in r.events)  # the leader aborted nothing
    np.testing.assert_allclose(r.metrics[:, 1:], batch()[:, 1:], rtol=0, atol=TOL)


def test_a_flood_of_replayed_poses_is_refused_and_what_it_drowned_is_sent_again(ros_env,
                                                                                  tmp_path):
    """From trial 2, a second process floods every robot's pose and shared-pose topics for
    5 s with replays of their traffic (tests/stack/forger.py --pose-flood), as fast as it
    can publish: the robots and the link emulator refuse and count them. The flood
    overwrites the readers' histories, real poses among them; the plant sends its stalled
    sample again, and every robot then sends again its shared poses of the trial, so the
    links get the one they lost. Before, the link emulator waited for a lost shared pose of
    a robot that had moved on, the plant timed out 20 s later and was restarted (twice in
    two runs; a 10 s flood once ended a run with status 4). Now the run finishes equal to
    batch without a restart."""
    proc = launch(ros_env, tmp_path, "paper-triangle3", "--trials", str(TRIALS), "--seed",
                  str(SEED))
    second = subprocess.Popen([sys.executable, str(Path(__file__).with_name("forger.py")),
                               "--pose-flood", "2"], env=ros_env, stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        out, err = proc.communicate(timeout=600)
        said = end_forger(second)
    finally:
        stop_group(proc)
        stop_group(second)
    flood = [json.loads(ln) for ln in said.splitlines() if ln.startswith("{")]
    assert [d["forged"] for d in flood] == ["pose_flood"] and flood[0]["topics"] >= 3, said
    assert proc.returncode == 0, out + err
    got = read_metrics(tmp_path / "metrics.csv")
    np.testing.assert_allclose(got[:, 1:], batch()[:, 1:], rtol=0, atol=TOL)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["restarts"] == {}
    diag = json.loads((tmp_path / "diagnostics.json").read_text())
    refused = {n: sum(diag[n]["dropped"][r] for r in ("stale", "duplicate"))
               for n in ("robot_1", "robot_2", "robot_3", "link_emulator")}
    print(f"pose flood: {flood[0]['count']} replays published; refused: {refused}; the "
          f"plant sent a sample again {diag['robot_sim']['resends']} times")
    assert all(v > 0 for v in refused.values()), refused


def test_a_run_waiting_for_a_node_that_never_comes_stops_naming_it(ros_env, tmp_path):
    """The schedule waits for an external plant node that never starts: the leader names
    it on the console past its bound, retries, then stops; the launcher exits 4 with the
    leader's one line and the resume command, instead of waiting in silence forever."""
    proc = launch(ros_env, tmp_path, "paper-triangle3", "--trials", "3", "--plant",
                  "external", "--plant-nodes", "ghost_plant", "--watchdog-scale", "0.1")
    try:
        out, err = proc.communicate(timeout=600)
    finally:
        stop_group(proc)
    assert proc.returncode == 4, out + err
    assert "virtual_leader: trial 0 has waited" in out and "ghost_plant has not said ready " \
        "(never seen)" in out, out
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("error: virtual_leader: stuck: ") and "ghost_plant" in lines[0]
    assert f"formation-ilc launch --resume {tmp_path}" in lines[0]
    assert "Traceback" not in out + err


def test_a_start_up_that_cannot_complete_names_the_unmatched_endpoints(ros_env, tmp_path):
    """The plant never starts: each robot waits for its pose's writer and its command's
    reader and says so in its diagnostics; past the start-up bound the leader names them
    with the endpoints they wait for, reads the readies anew once, and stops (its first
    start-up has no retries: nothing was lost that a retry could bring back)."""
    proc = launch(ros_env, tmp_path, "paper-triangle3", "--trials", "3", "--plant",
                  "external", "--plant-nodes", "ghost_plant", "--watchdog-scale", "0.25")
    try:
        out, err = proc.communicate(timeout=600)
    finally:
        stop_group(proc)
    assert proc.returncode == 4, out + err
    named = [ln for ln in out.splitlines() if ln.startswith("virtual_leader: trial 0 has ")]
    assert named, out
    assert "reading the readies anew" in named[0], named
    assert "robot_1 has not said ready" in named[0], named
    robot_1 = named[0].split("robot_1 has not said ready", 1)[1].split("robot_2", 1)[0]
    assert "it waits for " in robot_1, named
    assert "/formation/robot_1/pose: 0 of 1 writers" in robot_1, named
    assert "/formation/robot_1/cmd_vel: 0 of 1 readers" in robot_1, named
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "the readies read anew once without progress" in lines[0], err


def test_a_full_disk_stops_the_run_with_one_line_and_the_resume_command(ros_env, tmp_path):
    """The run's folder is a small file system of its own (a tmpfs in a mount namespace of
    the launcher's); after two trials the test fills it. Before: every node died with
    ENOSPC, was restarted 5 times for nothing, and the run ended with a line naming no file.
    Now: status 5, no restart, one line naming the file, what was kept, and how to go on."""
    if subprocess.run(["unshare", "-m", "true"], capture_output=True).returncode != 0:
        pytest.skip("no mount namespaces here")
    out_dir = tmp_path / "fs"
    out_dir.mkdir()
    prefix = ["unshare", "-m", "sh", "-c",
              f'mount -t tmpfs -o size=16m tmpfs "{out_dir}" && exec "$@"', "sh"]
    proc = launch(ros_env, out_dir, "paper-triangle3", "--trials", str(TRIALS), "--seed",
                  str(SEED), prefix=prefix)
    try:
        inside = None
        deadline = time.monotonic() + 600
        while proc.poll() is None and time.monotonic() < deadline:
            # the launcher's view of its folder (its own mount namespace)
            launcher = _launcher_pid(proc.pid)
            view = Path(f"/proc/{launcher}/root{out_dir}") if launcher else None
            if view is not None and _rows(view / "metrics.csv") >= 2:
                inside = view
                break
            time.sleep(0.2)  # polling a file, bounded by the deadline
        assert inside is not None, proc.communicate(timeout=60)
        # every free byte, unbuffered: a buffered file's close would write its rest again
        # and raise ENOSPC itself
        with open(inside / "filler", "wb", buffering=0) as fh:
            try:
                while fh.write(b"\0" * (1 << 16)):
                    pass
            except OSError:
                pass
        out, err = proc.communicate(timeout=600)
    finally:
        stop_group(proc)
    assert proc.returncode == 5, out + err
    assert "starting it again" not in out, out
    lines = [ln for ln in err.strip().splitlines() if ln.startswith("error:")]
    assert len(lines) == 1 and "the disk is full: " in lines[0], err
    assert f"formation-ilc launch --resume {out_dir}" in lines[0]
    assert "Traceback" not in err


def _launcher_pid(pid: int) -> int | None:
    """The launcher (python) under the ``unshare ... sh -c exec`` wrapper: the same pid
    once the shell has exec'd it."""
    try:
        cmd = Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return None
    return pid if b"formation_ilc.cli" in cmd else None


def _rows(path: Path) -> int:
    try:
        return max(0, len(path.read_text().splitlines()) - 1)
    except OSError:
        return 0


class ClockWatch(Peer):
    """A peer that counts how often each /clock stamp went out: a stamp seen again is a
    re-send of the plant."""

    def __init__(self, context):
        from rosgraph_msgs.msg import Clock

        super().__init__(context, "clock_watch")
        self.seen: Counter[int] = Counter()
        self.last = -1
        self.node.create_subscription(Clock, ms.CLOCK, self._clock, ms.CLOCK_QOS)

    def _clock(self, msg) -> None:
        self.last = msg.clock.sec * 1_000_000_000 + msg.clock.nanosec
        self.seen[self.last] += 1


def test_a_stalled_robot_makes_the_plant_resend_and_the_run_stays_equal_to_batch(
        ros_env, context, tmp_path):
    """robot_2 is stopped (SIGSTOP) early in trial 1 and held until the plant has sent its
    sample out twice more (seen on /clock): the robot, once it runs again, finds copies of
    its current sample in its queue and commands once; the run is equal to batch (a
    re-sent sample never changes what a robot learns).

    Stopped at a moment picked from the process table alone (CI stop 24), the robot could
    land between two trials, where the leader, not the plant, waits for it: no re-send."""
    import signal

    from formation_ilc.core.clock import SampleClock
    from formation_ilc.protocol.plant import RESEND_S

    from ..procs import find_child

    sc = load_scenario("paper-triangle3")
    grid = SampleClock.for_run(sc.dt, sc.samples)
    proc = launch(ros_env, tmp_path, "paper-triangle3", "--trials", str(TRIALS), "--seed",
                  str(SEED))
    watch = None
    try:
        deadline = time.monotonic() + 600
        while not (tmp_path / "metrics.csv").exists():  # the formation runs: join it
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.1)  # waiting for the launcher, bounded by the deadline
        victim = find_child(ros_env["ROS_DOMAIN_ID"], "robot_id:=2", deadline)
        watch = ClockWatch(context)
        # early in trial 1: the plant still has most of the trial to wait on the robot in
        while watch.last < 0 or grid.decode(watch.last)[0] < 1 \
                or grid.decode(watch.last)[1] > sc.samples // 4:
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            watch.spin()
        os.kill(victim, signal.SIGSTOP)
        try:
            stopped = time.monotonic()
            # the plant re-sends the sample it waits on, the last one it sent
            while time.monotonic() - stopped < 10 * RESEND_S \
                    and watch.seen[watch.last] < 3:  # sent, and sent again twice
                watch.spin()
        finally:
            os.kill(victim, signal.SIGCONT)
        out, err = proc.communicate(timeout=600)
    finally:
        stop_group(proc)
        if watch is not None:
            watch.close()
    assert proc.returncode == 0, out + err
    assert watch is not None and watch.seen[watch.last] >= 3, \
        f"the last sample did not go out three times while robot_2 was stopped: " \
        f"{watch and watch.seen.most_common(3)}"
    got = read_metrics(tmp_path / "metrics.csv")
    np.testing.assert_allclose(got[:, 1:], batch()[:, 1:], rtol=0, atol=TOL)
    diag = json.loads((tmp_path / "diagnostics.json").read_text())
    assert diag["robot_sim"]["resends"] >= 2, diag["robot_sim"]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["restarts"] == {}
