"""Multi-process tests of the distributed stack: real node processes on localhost.

Each test runs ``formation-ilc launch`` (leader, simulator + link emulator, one process per
robot) on its own ROS_DOMAIN_ID and compares what the robots learned over the wire with
the batch simulator on the same scenario and seed.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from formation_ilc.config.scenario import load_scenario
from formation_ilc.core.metrics import read_metrics
from formation_ilc.model.simulate import simulate

from ..procs import find_child, stop_group

pytestmark = [pytest.mark.ros, pytest.mark.multiprocess]

# Where the stack and the batch simulator may differ: headings travel as quaternions
# (sin, cos of theta/2 and back through atan2), a round-off of about 1 ulp per message.
# The learning loop is contracting, so it stays near 1e-13; 1e-9 is the required bound.
TOL = 1e-9


def launch(env: dict[str, str], out: Path, *args: str, timeout: float = 240.0,
           container: int = 0) -> subprocess.CompletedProcess[str]:
    argv = [sys.executable, "-m", "formation_ilc.cli", "launch", *args, "--out", str(out),
            "--domain-id", env["ROS_DOMAIN_ID"], "--no-plots", "--timeout", "20"]
    if container:
        argv += ["--container", str(container)]
    proc = subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, start_new_session=True)
    try:
        stdout, _ = proc.communicate(timeout=timeout)
    finally:
        stop_group(proc)  # never leave a stack behind, even on failure
    return subprocess.CompletedProcess(argv, proc.returncode, stdout, "")


CASES = [
    ("paper-triangle3", False, 0),
    ("paper-triangle3", True, 0),
    ("paper-hexagon6", False, 0),
    ("paper-hexagon6", True, 2),  # container mode: 3 processes of 2 robot nodes
]


@pytest.mark.slow
@pytest.mark.parametrize(("scenario", "uncertain", "container"), CASES,
                         ids=[f"{s}-{'noisy' if u else 'clean'}{'-container' if c else ''}"
                              for s, u, c in CASES])
def test_lockstep_stack_equals_batch_simulator(ros_env, tmp_path, scenario, uncertain,
                                               container):
    trials = 20
    flags = [] if uncertain else ["--no-noise", "--no-delay"]
    res = launch(ros_env, tmp_path, scenario, "--trials", str(trials), "--seed", "5", *flags,
                 container=container)
    assert res.returncode == 0, res.stdout
    assert f"trial {trials - 1} of 0..{trials - 1}" in res.stdout
    got = read_metrics(tmp_path / "metrics.csv")
    sc = load_scenario(scenario).with_options(noise=uncertain, delay=uncertain, seed=5)
    ref = simulate(sc, trials=trials).metrics
    assert got.shape == ref.shape
    np.testing.assert_array_equal(got[:, 0], ref[:, 0])
    np.testing.assert_allclose(got[:, 1:], ref[:, 1:], rtol=0, atol=TOL)
    # learning works over the wire: the error falls across trials. The hexagon's max
    # position error has a transient that peaks near trial 20 (in the batch simulator as
    # well, see `formation-ilc check paper-hexagon6`); its heading error falls at once.
    if scenario == "paper-triangle3":
        assert got[-1, 1] < 0.5 * got[0, 1]
    else:
        assert got[-1, 2] < 0.85 * got[0, 2]
    assert_no_unexplained_drops(json.loads((tmp_path / "diagnostics.json").read_text()))
    if uncertain:
        check_delay_histograms(tmp_path, sc)


def test_through_the_launchers_discovery_server(ros_env, tmp_path):
    """``--discovery server`` (the default from 64 processes: 100 robots, one process each,
    start on 2 cores only so): every process a client of Fast DDS's discovery server, which
    the launcher starts on 127.0.0.1 and stops. The run equals the batch simulator."""
    trials = 4
    res = launch(ros_env, tmp_path, "paper-triangle3", "--trials", str(trials), "--seed", "5",
                 "--discovery", "server")
    assert res.returncode == 0, res.stdout
    assert "discovery: through Fast DDS's discovery server on 127.0.0.1:" in res.stdout
    got = read_metrics(tmp_path / "metrics.csv")
    ref = simulate(load_scenario("paper-triangle3").with_options(seed=5), trials=trials).metrics
    np.testing.assert_allclose(got[:, 1:], ref[:, 1:], rtol=0, atol=TOL)
    assert (tmp_path / "logs" / "discovery_server.log").exists()  # the server's console


def assert_no_unexplained_drops(diag: dict, where: str = "") -> None:
    """No node dropped a message, except the copies of a sample the plant sent again (a
    command still due 2 s after the sample went out, on a loaded machine: the liveness
    re-send), which every reader that already had it drops as a duplicate."""
    resent = sum(int(d.get("resends", 0)) for d in diag.values())
    for node, d in diag.items():
        dropped = dict(d.get("dropped", {}))
        if resent:
            dropped.pop("duplicate", None)
        assert sum(dropped.values()) == 0, (where, node, d["dropped"], resent)


def check_delay_histograms(out: Path, sc) -> None:
    """The robots' eq. (11) measurements equal what the links injected, and follow the
    scenario's delay model (the paper's kappa table) within a few percent."""
    with (out / "delays.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert rows
    links = {r["link"] for r in rows}
    assert any(link.startswith("leader->") for link in links)
    total: dict[int, int] = {}
    for r in rows:
        assert int(r["measured"]) == int(r["injected"]), r
        total[int(r["tau"])] = total.get(int(r["tau"]), 0) + int(r["measured"])
    n = sum(total.values())
    for tau, p in sc.uncertainty.delay.pmf().items():
        assert abs(total.get(tau, 0) / n - p) < 0.03, (tau, total, n)


def test_dead_robot_is_named_and_stack_stops(ros_env, tmp_path):
    """With restarts off, a node that dies ends the run, naming it (tests/stack/test_faults.py:
    with restarts on, the run goes on)."""
    argv = [sys.executable, "-m", "formation_ilc.cli", "launch", "paper-triangle3",
            "--trials", "200", "--out", str(tmp_path), "--domain-id", ros_env["ROS_DOMAIN_ID"],
            "--no-plots", "--max-restarts", "0"]
    proc = subprocess.Popen(argv, env=ros_env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        # wait until the first trial is done, then kill robot 2 the hard way
        deadline = time.monotonic() + 120
        metrics = tmp_path / "metrics.csv"
        while time.monotonic() < deadline:
            if metrics.exists() and len(metrics.read_text().splitlines()) >= 2:
                break
            assert proc.poll() is None, proc.communicate()[0]
            time.sleep(0.1)
        victim = find_child(ros_env["ROS_DOMAIN_ID"], "robot_id:=2", deadline)
        os.kill(victim, signal.SIGKILL)
        out, _ = proc.communicate(timeout=60)
    finally:
        stop_group(proc, signal.SIGKILL)
    assert proc.returncode == 1, out
    assert "robot_2 exited with signal SIGKILL" in out
    # every other node of the stack was stopped
    with pytest.raises(AssertionError):
        find_child(ros_env["ROS_DOMAIN_ID"], "-m robot_sim.node", time.monotonic() + 1)


def test_ament_layout_for_ros2_run(tmp_path):
    """A wheel install has the ament index marker, package.xml and executables under
    lib/formation_ilc/, found by ament_index_python through AMENT_PREFIX_PATH."""
    repo = Path(__file__).resolve().parents[2]  # tests/stack/ -> the repository
    wheel_dir = tmp_path / "wheel"
    prefix = tmp_path / "prefix"
    subprocess.run([sys.executable, "-m", "pip", "wheel", str(repo), "--no-deps", "-q",
                    "-w", str(wheel_dir)], check=True, timeout=300)
    wheel = next(wheel_dir.glob("formation_ilc-*.whl"))
    # install the wheel's data files into the prefix as pip does (``pip install --prefix``
    # would also uninstall the venv's own copy of the package)
    import zipfile

    with zipfile.ZipFile(wheel) as zf:
        for info in zf.infolist():
            head, _, rest = info.filename.partition(".data/data/")
            if not rest or "/" in head:
                continue
            dest = prefix / rest
            dest.parent.mkdir(parents=True, exist_ok=True)
            dest.write_bytes(zf.read(info))
            mode = (info.external_attr >> 16) & 0o777
            if mode:
                dest.chmod(mode)
    code = (
        "import os, sys\n"
        "from ament_index_python.packages import get_package_prefix, "
        "get_package_share_directory\n"
        "p = get_package_prefix('formation_ilc')\n"
        "s = get_package_share_directory('formation_ilc')\n"
        "print(p); print(s)\n"
    )
    env = dict(os.environ, AMENT_PREFIX_PATH=str(prefix))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, check=True, timeout=60).stdout.split()
    assert Path(out[0]) == prefix
    assert (Path(out[1]) / "package.xml").is_file()
    for exe in ("robot", "robot_sim", "link_emulator", "virtual_leader", "recorder",
                "bridge", "pioneer_bridge"):  # the bridge's old name, for one release
        f = prefix / "lib" / "formation_ilc" / exe
        assert f.is_file() and os.access(f, os.X_OK), f
    for launch in ("formation.launch.py", "robot.launch.py"):
        assert (Path(out[1]) / "launch" / launch).is_file()
    # an entry script starts (and documents its parameters)
    res = subprocess.run([sys.executable, str(prefix / "lib/formation_ilc/robot"), "--help"],
                         env=dict(os.environ, ROS_DOMAIN_ID="99",
                                  ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST"),
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert "robot_id" in res.stdout


def test_bad_messages_are_dropped_and_counted(ros_env, tmp_path):
    """Malformed, stale and out-of-order messages injected into a running stack are dropped,
    counted on /formation/diagnostics, and change nothing: the run still equals the batch."""
    import rclpy
    from geometry_msgs.msg import PoseStamped, Twist
    from nav_msgs.msg import Path as PathMsg
    from rclpy.context import Context
    from std_msgs.msg import String

    import msgs_schema as ms

    trials = 40
    argv = [sys.executable, "-m", "formation_ilc.cli", "launch", "paper-triangle3",
            "--trials", str(trials), "--out", str(tmp_path), "--domain-id",
            ros_env["ROS_DOMAIN_ID"], "--no-plots"]
    proc = subprocess.Popen(argv, env=ros_env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    ctx = Context()
    rclpy.init(context=ctx)
    node = None
    try:
        sc = load_scenario("paper-triangle3")
        clk = ms.SampleClock.for_run(sc.dt, sc.samples)
        node_ns = dict(namespace=ms.NAMESPACE)
        # the injector joins once the run is under way (a node in the namespace before the
        # launch would be taken for another formation, and the launch refused)
        deadline = time.monotonic() + 120
        metrics = tmp_path / "metrics.csv"
        while not (metrics.exists() and len(metrics.read_text().splitlines()) >= 2):
            assert proc.poll() is None, proc.communicate()[0]
            assert time.monotonic() < deadline, "the stack did not get to trial 1"
            time.sleep(0.05)
        node = rclpy.create_node("injector", context=ctx, **node_ns)
        pubs = {
            "pose": node.create_publisher(PoseStamped, ms.pose_topic(2), ms.SAMPLE_QOS),
            "link": node.create_publisher(PathMsg, ms.link_topic(2, "robot_1"), ms.SAMPLE_QOS),
            "traj": node.create_publisher(PathMsg, ms.trajectory_topic(1),
                                          ms.TRAJECTORY_QOS),
            "cmd": node.create_publisher(Twist, ms.cmd_vel_topic(3), ms.SAMPLE_QOS),
            "shared": node.create_publisher(PoseStamped, ms.shared_pose_topic(1),
                                            ms.SAMPLE_QOS),
            "ready": node.create_publisher(String, ms.READY, ms.LATCHED_QOS),
        }
        deadline = time.monotonic() + 120
        metrics = tmp_path / "metrics.csv"
        while time.monotonic() < deadline:
            rows = len(metrics.read_text().splitlines()) - 1 if metrics.exists() else 0
            if rows >= 3 and all(p.get_subscription_count() >= 1 for p in pubs.values()):
                break
            assert proc.poll() is None, proc.communicate()[0]
            time.sleep(0.05)
        else:
            raise AssertionError("the stack did not get to trial 3")
        world = ms.WORLD_FRAME
        nan_pose = ms.pose_to_msg([float("nan"), 0.0, 0.0], clk.stamp_ns(5, 3), world)
        stale_pose = ms.pose_to_msg([0.0, 0.0, 0.0], clk.stamp_ns(0, 5), world)
        future_pose = ms.pose_to_msg([0.0, 0.0, 0.0], clk.stamp_ns(999, 5), world)
        bad_q = ms.pose_to_msg([0.0, 0.0, 0.0], clk.stamp_ns(5, 3), world)
        bad_q.pose.orientation.x = 0.7
        two = ms.link_tick_to_msg(clk.stamp_ns(0, 1), stale_pose)
        two.poses.append(stale_pose)
        short = ms.trajectory_to_path(np.zeros((3, 3)), [clk.stamp_ns(1, s) for s in range(3)],
                                      world)
        stale = ms.trajectory_to_path(np.zeros((sc.samples + 1, 3)),
                                      [clk.stamp_ns(0, s) for s in range(sc.samples + 1)],
                                      world)
        t = Twist()
        t.linear.x = float("inf")
        bad = [("pose", m) for m in (nan_pose, stale_pose, future_pose, bad_q)] + [
            ("link", two),  # two poses in one tick
            ("link", ms.link_tick_to_msg(clk.stamp_ns(0, 1), None)),  # trial 0
            ("traj", short), ("traj", stale), ("cmd", t),
            ("shared", ms.pose_to_msg([0, 0, 0], clk.stamp_ns(0, 2), "robot_9")),  # frame
            ("ready", String(data="{not json"))]
        # twice, 1 s apart: a volatile message sent before one of its readers matched the
        # injector is lost; the counts below are lower bounds, and the second round is
        # counted the same way (malformed, stale or future whatever the trial then)
        for round_ in range(2):
            for topic, m in bad:
                pubs[topic].publish(m)
            if round_ == 0:
                time.sleep(1.0)
        out, _ = proc.communicate(timeout=180)
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown(context=ctx)
        stop_group(proc)
    assert proc.returncode == 0, out
    diag = json.loads((tmp_path / "diagnostics.json").read_text())
    r2 = diag["robot_2"]["dropped"]
    assert r2["malformed"] >= 2 + 1      # NaN pose, tilted pose, two-pose tick
    assert r2["stale"] >= 2              # old pose, old tick
    # the short and the trial-0 trajectory on robot_1's topic: not from robot_1's writer,
    # refused before they are read (latched: both rounds reach robot 2)
    assert r2["forged"] >= 2
    assert diag["robot_2"]["forged"]["/formation/robot_1/trajectory"][
        "/formation/injector"] == r2["forged"], diag["robot_2"]["forged"]
    assert r2["future"] >= 1             # a pose of trial 999 mid-trial: outside the window
    assert diag["robot_sim"]["dropped"]["malformed"] >= 1
    assert diag["link_emulator"]["dropped"]["malformed"] >= 1
    got = read_metrics(tmp_path / "metrics.csv")
    ref = simulate(load_scenario("paper-triangle3"), trials=trials).metrics
    np.testing.assert_allclose(got[:, 1:], ref[:, 1:], rtol=0, atol=TOL)


def start_launch(env: dict[str, str], out: Path, *args: str) -> subprocess.Popen[str]:
    argv = [sys.executable, "-m", "formation_ilc.cli", "launch", *args, "--out", str(out),
            "--domain-id", env["ROS_DOMAIN_ID"], "--no-plots", "--timeout", "20"]
    return subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, start_new_session=True)


DIRECT_CASES = [("paper-hexagon6", False), ("paper-hexagon6", True)]


@pytest.mark.slow
@pytest.mark.parametrize(("scenario", "noisy"), DIRECT_CASES,
                         ids=[f"{s}-{'noisy' if u else 'clean'}" for s, u in DIRECT_CASES])
def test_lockstep_direct_links_equal_batch_without_delay(ros_env, tmp_path, scenario, noisy):
    """Robots subscribe to each other, no link emulator process: in lockstep every robot
    waits for its neighbours' sample-t poses, so the run is `simulate --no-delay`."""
    trials = 12
    flags = [] if noisy else ["--no-noise"]
    res = launch(ros_env, tmp_path, scenario, "--trials", str(trials), "--seed", "5",
                 "--links", "direct", *flags)
    assert res.returncode == 0, res.stdout
    assert "link_emulator" not in {p.stem for p in (tmp_path / "logs").iterdir()}
    got = read_metrics(tmp_path / "metrics.csv")
    sc = load_scenario(scenario).with_options(noise=noisy, delay=False, seed=5)
    ref = simulate(sc, trials=trials).metrics
    np.testing.assert_array_equal(got[:, 0], ref[:, 0])
    np.testing.assert_allclose(got[:, 1:], ref[:, 1:], rtol=0, atol=TOL)
    # the robots measured every link's delay by eq. (11): 0 samples in lockstep
    with (tmp_path / "delays.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    links = {r["link"] for r in rows}
    assert links == {f"{s}->robot_{i + 1}" for i in range(sc.n)
                     for s in ([f"robot_{j + 1}" for j in sc.graph.neighbours(i)]
                               + (["leader"] if sc.graph.leader[i] > 0 else []))}
    for r in rows:
        assert r["injected"] == ""  # no emulator: the network's delays are only measured
        assert int(r["measured"]) == (trials * sc.samples if r["tau"] == "0" else 0), r
    assert_no_unexplained_drops(json.loads((tmp_path / "diagnostics.json").read_text()))


def test_told_commands_cross_the_graph_and_the_filter_uses_them(ros_env, tmp_path):
    """With the paper's noise, each robot tells the others the command it applied
    (``robot_i/applied``, the default up to 12 robots) and their filters take the others'
    speeds from it, waiting in lockstep for every one: the run through the filter is the
    batch simulator's with told speeds, to round-off, and not the one with speeds
    estimated from poses (the filter acts on both, differently)."""
    from formation_ilc.model.safety import body_spec

    trials = 4
    res = launch(ros_env, tmp_path, "paper-triangle3", "--trials", str(trials), "--seed", "5",
                 "--safety")
    assert res.returncode == 0, res.stdout
    got = read_metrics(tmp_path / "metrics.csv")
    sc = load_scenario("paper-triangle3").with_options(seed=5)
    told = simulate(sc, trials=trials,
                    safety=body_spec("p3dx", sc.dt, sc.uncertainty, "commands")).metrics
    guessed = simulate(sc, trials=trials,
                       safety=body_spec("p3dx", sc.dt, sc.uncertainty, "poses")).metrics
    np.testing.assert_allclose(got[:, 1:], told[:, 1:], rtol=0, atol=TOL)
    assert told[:, 7].sum() > 0 and np.abs(told[:, 1:8] - guessed[:, 1:8]).max() > 1e-3
    diag = json.loads((tmp_path / "diagnostics.json").read_text())
    for i in range(1, sc.n + 1):
        assert diag[f"robot_{i}"]["filter_total"]["untold"] == 0, diag[f"robot_{i}"]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["safety"]["motion"] == "commands"
    assert_no_unexplained_drops(diag)


def test_two_formations_share_a_domain_under_two_namespaces(ros_env, tmp_path):
    """Two launches on one ROS_DOMAIN_ID at the same time, in /team_a (emulated links) and
    /team_b (direct links): each equals its own batch run, so nothing crossed over."""
    runs = {"/team_a": ("emulated", "3"), "/team_b": ("direct", "4")}
    procs = {}
    try:
        for ns, (links, seed) in runs.items():
            procs[ns] = start_launch(ros_env, tmp_path / ns[1:], "paper-triangle3", "--trials",
                                     "8", "--seed", seed, "--links", links, "--namespace", ns)
        outs = {ns: p.communicate(timeout=240)[0] for ns, p in procs.items()}
    finally:
        for p in procs.values():
            stop_group(p)
    for ns, (links, seed) in runs.items():
        assert procs[ns].returncode == 0, outs[ns]
        assert f"namespace {ns}" in outs[ns]
        got = read_metrics(tmp_path / ns[1:] / "metrics.csv")
        sc = load_scenario("paper-triangle3").with_options(seed=int(seed),
                                                           delay=links == "emulated")
        np.testing.assert_allclose(got[:, 1:], simulate(sc, trials=8).metrics[:, 1:],
                                   rtol=0, atol=TOL)
        assert_no_unexplained_drops(json.loads((tmp_path / ns[1:] / "diagnostics.json")
                                                .read_text()), ns)


def test_a_stand_in_plant_that_speaks_only_the_contract(ros_env, tmp_path):
    """The simulator replaced by tests/stack/standin_plant.py (no true state, no diagnostics):
    the team still learns, and the true-state columns say they are absent (nan)."""
    trials = 6
    # beside this file: run from tests/, its folders (tests/msgs_schema/, ...) would
    # shadow the packages they test
    standin = Path(__file__).resolve().parent / "standin_plant.py"
    plant = subprocess.Popen([sys.executable, str(standin)],
                             env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                             text=True, start_new_session=True)
    try:
        res = launch(ros_env, tmp_path, "paper-triangle3", "--trials", str(trials),
                     "--no-noise", "--links", "direct", "--plant", "external",
                     "--plant-nodes", "standin_plant", "--record", str(tmp_path / "run.mcap"))
    finally:
        stop_group(plant)
        plant_log = plant.communicate()[0]
    assert res.returncode == 0, res.stdout + plant_log
    assert "true state: the plant publishes none" in res.stdout
    got = read_metrics(tmp_path / "metrics.csv")
    assert got.shape == (trials, 9)
    assert np.isnan(got[:, 3:5]).all()          # true_max_position/heading_error
    assert np.isfinite(got[:, [1, 2, 5, 6]]).all()
    assert got[-1, 1] < 0.5 * got[0, 1]         # it learns
    # the same plant model as the batch simulator without noise: the same numbers
    ref = simulate(load_scenario("paper-triangle3").with_options(noise=False, delay=False),
                   trials=trials).metrics
    np.testing.assert_allclose(got[:, [1, 2, 5, 6]], ref[:, [1, 2, 5, 6]], rtol=0, atol=1e-9)
    # the recording of such a run (no true state, direct links) analyses to the same rows
    from formation_ilc.cli import main

    assert main(["analyze", str(tmp_path / "run.mcap"), "--out", str(tmp_path / "an")]) == 0
    np.testing.assert_array_equal(read_metrics(tmp_path / "an" / "metrics.csv"), got)
    with (tmp_path / "an" / "delays.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert rows and all(r["injected"] == r["model_probability"] == "" for r in rows)
