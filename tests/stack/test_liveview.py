"""What the formation should be, recorded and live (issue 18, part B).

A launch with --record holds each robot's desired poses and paths, its tracking errors (per
sample, equal to the errors recomputed from the recorded poses; per trial, whose largest is
the metrics row's) and the markers, and analyses to the launcher's metrics as before. A
launch with --live serves the running formation to a client that is not this project's:
Foxglove's own ``@foxglove/ws-protocol`` client with ``@foxglove/rosmsg2-serialization``
(tests/stack/foxglove_client/, run with node), which must decode poses, errors, desired
poses and markers while the lockstep run, still equal to the batch simulator, goes on.

Without node/npm or foxglove-sdk the live test skips, unless FORMATION_ILC_REQUIRE_LIVE=1
(CI sets it): then it fails.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mcap_ros2")  # the [mcap] extra; CI installs it

from formation_ilc.cli import main  # noqa: E402
from formation_ilc.config.runconfig import RunConfig  # noqa: E402
from formation_ilc.config.scenario import load_scenario  # noqa: E402
from formation_ilc.core.metrics import read_metrics  # noqa: E402
from formation_ilc.model.simulate import simulate  # noqa: E402
from formation_ilc.protocol.view import TrackingView  # noqa: E402
from formation_ilc.recordings.mcap_io import read_messages  # noqa: E402

from ..procs import stop_group  # noqa: E402
from .test_stack import TOL, launch  # noqa: E402

CLIENT = Path(__file__).parent / "foxglove_client"
REQUIRE = os.environ.get("FORMATION_ILC_REQUIRE_LIVE") == "1"


@pytest.mark.ros
@pytest.mark.multiprocess
def test_recording_holds_desired_poses_errors_and_markers(ros_env, tmp_path):
    from geometry_msgs.msg import PoseStamped, Vector3Stamped
    from nav_msgs.msg import Path as PathMsg
    from rclpy.serialization import deserialize_message
    from visualization_msgs.msg import MarkerArray

    import msgs_schema as ms

    rec = tmp_path / "run.mcap"
    res = launch(ros_env, tmp_path / "launch", "paper-triangle3", "--trials", "2", "--seed",
                 "3", "--record", str(rec))
    assert res.returncode == 0, res.stdout
    launched = read_metrics(tmp_path / "launch" / "metrics.csv")
    assert main(["analyze", str(rec), "--out", str(tmp_path / "an"), "--no-plots"]) == 0
    np.testing.assert_array_equal(read_metrics(tmp_path / "an" / "metrics.csv"), launched)

    sc = load_scenario("paper-triangle3")
    view = TrackingView(sc.desired.eta)
    clock = RunConfig(sc).clock  # the launcher's sample grid (default gap)
    msgs = list(read_messages(rec))
    counts = Counter(m.topic for m in msgs)
    poses: dict[tuple[int, int], np.ndarray] = {}
    errors: dict[tuple[int, int], tuple[float, float]] = {}
    peaks = defaultdict(list)
    markers = 0
    for m in msgs:
        name = m.topic.removeprefix("/formation/")
        if name == ms.MARKERS:
            arr = deserialize_message(m.data, MarkerArray)
            # each robot's footprint and heading too, in its own frame (issue 54)
            assert {k.ns for k in arr.markers} == {"formation", "links", "errors", "labels",
                                                   "footprint", "heading"}
            assert sorted(k.header.frame_id for k in arr.markers if k.ns == "footprint") == \
                ["robot_1/base_link", "robot_2/base_link", "robot_3/base_link"]
            assert sorted(k.text for k in arr.markers if k.ns == "labels") == \
                ["robot_1", "robot_2", "robot_3"]
            markers += 1
            continue
        if not name.startswith("robot_"):
            continue
        robot, _, kind = name.partition("/")
        r = int(robot.removeprefix("robot_")) - 1
        if kind == "pose":
            eta, stamp = ms.world_pose(deserialize_message(m.data, PoseStamped))
            poses[(r, stamp)] = eta
        elif kind == "tracking_error":
            v = deserialize_message(m.data, Vector3Stamped)
            errors[(r, m.publish_time)] = (v.vector.x, v.vector.y)
        elif kind == "trial_error":
            v = deserialize_message(m.data, Vector3Stamped)
            peaks[int(v.vector.z)].append((v.vector.x, v.vector.y))
        elif kind == "desired_path":
            eta, _, _ = ms.path_to_trajectory(deserialize_message(m.data, PathMsg))
            np.testing.assert_allclose(eta[:, :2], sc.desired.eta[r, :, :2], atol=1e-12)
        elif kind == "desired_pose":
            eta, stamp = ms.world_pose(deserialize_message(m.data, PoseStamped))
            _, s = clock.decode(stamp)
            np.testing.assert_allclose(eta[:2], sc.desired.eta[r, s, :2], atol=1e-12)
    for i in (1, 2, 3):
        for kind in ("pose", "desired_pose", "tracking_error"):
            assert counts[f"/formation/robot_{i}/{kind}"] >= 2 * 141, kind
        assert counts[f"/formation/robot_{i}/desired_pose"] == counts[f"/formation/robot_{i}/pose"]
        assert counts[f"/formation/robot_{i}/desired_path"] == 2
        assert counts[f"/formation/robot_{i}/trial_error"] == 2
    assert markers == counts["/formation/markers"] >= 2 * 141 // max(1, round(0.5 / sc.dt))
    # every error is the recorded pose's, recomputed
    assert set(errors) == set(poses)
    for (r, stamp), eta in poses.items():
        _, s = clock.decode(stamp)
        pos, head = view.error(r, s, eta)
        assert errors[(r, stamp)][0] == pos
        assert abs(errors[(r, stamp)][1] - head) < 1e-12
    # the largest per-trial errors over robots are the metrics row's
    for row in launched:
        got = peaks[int(row[0])]
        assert len(got) == 3
        assert max(p[0] for p in got) == pytest.approx(row[1], abs=1e-12)
        assert max(p[1] for p in got) == pytest.approx(row[2], abs=1e-12)


def _client_modules(tmp_path: Path) -> Path:
    """node_modules of the client, installed once (``npm ci`` from the lock) into a cache
    folder named by the lock's hash; the test's own folder when the cache cannot be made."""
    node, npm = shutil.which("node"), shutil.which("npm")
    if node is None or npm is None:
        if REQUIRE:
            pytest.fail("node and npm are required (FORMATION_ILC_REQUIRE_LIVE=1)")
        pytest.skip("node/npm not installed")
    lock = (CLIENT / "package-lock.json").read_bytes()
    base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    cache = base / "formation-ilc" / f"foxglove-client-{hashlib.sha256(lock).hexdigest()[:16]}"
    if not (cache / "node_modules" / ".done").exists():
        cache.mkdir(parents=True, exist_ok=True)
        for f in ("package.json", "package-lock.json"):
            shutil.copy(CLIENT / f, cache / f)
        res = subprocess.run([npm, "ci", "--prefer-offline", "--no-audit", "--no-fund",
                              "--ignore-scripts"],
                             cwd=cache, capture_output=True, text=True, timeout=600)
        assert res.returncode == 0, res.stdout + res.stderr
        (cache / "node_modules" / ".done").write_text("")
    return cache / "node_modules"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.ros
@pytest.mark.multiprocess
def test_live_view_serves_a_foxglove_client_during_a_lockstep_run(ros_env, tmp_path):
    try:
        import foxglove  # noqa: F401
    except ImportError:
        if REQUIRE:
            pytest.fail("foxglove-sdk (the 'live' extra) is required")
        pytest.skip("foxglove-sdk not installed (the 'live' extra)")
    modules = _client_modules(tmp_path)
    port = _free_port()
    # more trials than the viewers need: the run is interrupted once both have been served,
    # so a fast run cannot end (and close the server) before the late viewer has joined
    trials = 500
    out = tmp_path / "launch"
    argv = [sys.executable, "-m", "formation_ilc.cli", "launch", "paper-triangle3", "--trials",
            str(trials), "--seed", "4", "--out", str(out), "--domain-id",
            ros_env["ROS_DOMAIN_ID"], "--no-plots", "--timeout", "20", "--live", str(port)]
    stack = subprocess.Popen(argv, env=ros_env, stdout=subprocess.PIPE,
                             stderr=subprocess.STDOUT, text=True, start_new_session=True)
    topics = ["robot_1/pose", "robot_3/pose", "robot_2/tracking_error",
              "robot_2/desired_pose", "markers"]
    env = {**ros_env, "NODE_PATH": str(modules)}
    result = None
    try:
        deadline = time.monotonic() + 200
        while stack.poll() is None and time.monotonic() < deadline:
            c = subprocess.run(["node", str(CLIENT / "client.js"), f"ws://127.0.0.1:{port}",
                                "20", *topics], env=env, capture_output=True, text=True,
                               timeout=150)
            last = (c.stdout.strip().splitlines() or [""])[-1]
            result = json.loads(last) if last.startswith("{") else {"error": c.stderr}
            if c.returncode == 0 or "ECONNREFUSED" not in str(result.get("error")):
                break
            time.sleep(0.5)  # the server is not up yet
        if result is None or not result.get("ok"):
            stop_group(stack)
            pytest.fail(f"{result}\n{_log(out)}\n{stack.communicate()[0][-3000:]}")
        # a viewer that joins mid-run gets the latched state at once: the configuration
        # (published once, before the first client came), readies, desired paths and
        # diagnostics, as foxglove_bridge gives a late client transient-local topics
        late_topics = ["config", "ready", "robot_1/desired_path", "diagnostics",
                       "trial_events"]  # the current trial's start, not the next event
        # ... and the run's parameters, read-only
        c = subprocess.run(["node", str(CLIENT / "client.js"), f"ws://127.0.0.1:{port}", "1",
                            *late_topics, "@params"], env=env, capture_output=True,
                           text=True, timeout=150)
        running = stack.poll() is None
        last = (c.stdout.strip().splitlines() or [""])[-1]
        late = json.loads(last) if last.startswith("{") else {"error": c.stderr}
        if running:  # SIGINT, as Ctrl-C: the finished trials stay in metrics.csv
            os.killpg(stack.pid, signal.SIGINT)
        stdout = stack.communicate(timeout=120)[0]  # read while it stops: the pipe never fills
    finally:
        stop_group(stack)
    assert running, f"the run ended before the late viewer was served:\n{stdout[-3000:]}"
    assert late.get("ok"), f"{late}\n{_log(out)}"
    print(f"late viewer: first message after {late['first_ms']} ms")
    for t in late_topics:
        assert late["counts"][t] >= 1
    # the run's parameters as the leader has them, named as foxglove_bridge names them; a
    # change is answered with the value the run keeps
    params = late["params"]
    assert params["/formation/virtual_leader.seed"] == 4
    assert params["/formation/virtual_leader.trials"] == trials
    assert params["/formation/virtual_leader.scenario"] == "paper-triangle3"
    assert params["/formation/virtual_leader.mode"] == "lockstep"
    # ... and every node's own, read through its parameter services
    for node in ("robot_1", "robot_3", "robot_sim"):
        assert any(k.startswith(f"/formation/{node}.") for k in params), sorted(params)
    (name, kept), = late["set_answer"].items()
    assert kept == params[name], late["set_answer"]
    for t in topics:
        assert result["counts"][t] >= 20
        assert result["samples"][t]["topic"] == f"/formation/{t}"
    assert result["samples"]["robot_2/tracking_error"]["schema"] == \
        "geometry_msgs/msg/Vector3Stamped"
    assert stack.returncode == 130, stdout
    assert f"live view: ws://127.0.0.1:{port} (open it in Foxglove" in stdout  # the header
    # the view changed nothing: the trials the run finished equal the batch simulator's
    got = read_metrics(out / "metrics.csv")
    assert 1 <= len(got) < trials
    sc = load_scenario("paper-triangle3").with_options(seed=4)
    ref = simulate(sc, trials=len(got)).metrics
    np.testing.assert_array_equal(got[:, 0], ref[:, 0])
    np.testing.assert_allclose(got[:, 1:], ref[:, 1:], rtol=0, atol=TOL)


def _log(out: Path) -> str:
    log = out / "logs" / "liveview.log"
    return log.read_text()[-2000:] if log.exists() else "(no liveview log)"
