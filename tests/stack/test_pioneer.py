"""Multi-process tests of real-robot runs without robots: paper-triangle3 through three
Pioneer bridges against fake RosAria drivers (wall-clock trials at dT = 0.2 s, direct
links, the return to the initial pose between trials), and the sim-to-real carry-over of a
memory learned by the batch simulator."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from formation_ilc.cli import main as cli_main
from formation_ilc.config.scenario import load_scenario
from formation_ilc.core.metrics import read_metrics
from formation_ilc.model.simulate import simulate
from tests.procs import stop_group
from tests.stack.test_stack import launch, start_launch

pytestmark = [pytest.mark.ros, pytest.mark.multiprocess, pytest.mark.slow]

TRIALS = 3
# The fake drivers' odometry is off by 1 % in distance, -1 % in rotation, 0.002 rad/s bias
# and 2 mm noise; commands reach them a few ms after each sample instant; every start is
# off by up to the return tolerance (2 cm, 2 deg). Measured against the batch simulator
# without noise or delay, max position error per trial [m]: bridge 4.559 4.545 3.463 vs
# batch 4.587 4.559 3.425 (|diff| <= 0.038); another run 4.560 4.473 (|diff| <= 0.085).
# Allowed: a little over twice the largest difference seen.
BATCH_ATOL = 0.2
#: cold first-trial error (stack) of the bridge run, for the warm-start test
_cold: dict[str, float] = {}


def pioneer_args(*extra: str) -> list[str]:
    return ["paper-triangle3", "--plant", "pioneer", "--fake-drivers", "--no-noise",
            "--no-delay", "--return-timeout", "40", *extra]


def test_team_learns_through_bridges_and_fake_drivers(ros_env, tmp_path):
    """... managed bridges (--lifecycle): each starts unconfigured, and the launcher brings
    it up through its change_state service (tests/nodes/test_lifecycle_bridge.py: each
    transition on its own, and deactivate stopping the base)."""
    out = tmp_path / "run"
    # without the safety filter: through it, under CI load (3 test processes on 2 cores),
    # late peer poses made the filter brake (212 commands changed in trial 1 against 31,
    # up to 154 samples it could not show safe) and the team did not learn in 3 trials,
    # where the batch simulator, which has no late poses, does; 1 CI run in 4. The filter
    # on bridges is run by test_secure.py's pioneer test and in one process by
    # tests/nodes/test_bridge_inprocess.py
    res = launch(ros_env, out, *pioneer_args("--trials", str(TRIALS), "--lifecycle",
                                             "--no-safety"), timeout=400)
    assert res.returncode == 0, res.stdout
    assert "wallclock, direct links, plant bridge_1, bridge_2, bridge_3" in res.stdout
    for i in (1, 2, 3):
        assert f"/formation/bridge_{i}: configured and active (lifecycle)" in res.stdout
    assert "did not answer the deactivate request" not in res.stdout
    for i in (1, 2, 3):  # the launcher deactivated each at the end: its base stopped
        log = (out / "logs" / f"bridge_{i}.log").read_text()
        assert f"bridge_{i}: stopped: a zero command sent to /pioneer_{i}/cmd_vel" in log
    got = read_metrics(out / "metrics.csv")
    assert got.shape == (TRIALS, 9)
    # no true state from a real robot: the true_ columns are nan, the rest finite; no
    # bodies report contacts; no filter ran (--no-safety): it changed nothing
    assert np.isnan(got[:, 3:5]).all() and np.isfinite(got[:, [1, 2, 5, 6, 7]]).all()
    assert np.isnan(got[:, 8]).all() and (got[:, 7] == 0).all()
    summary = json.loads((out / "summary.json").read_text())
    assert "safety" not in summary
    sc = load_scenario("paper-triangle3").with_options(noise=False, delay=False)
    ref = simulate(sc, trials=TRIALS).metrics
    print("bridge max position error per trial:", got[:, 1].round(4).tolist())
    print("batch  max position error per trial:", ref[:, 1].round(4).tolist())
    # the team learns, as the batch simulator does
    assert got[-1, 1] < 0.85 * got[0, 1], got[:, 1]
    np.testing.assert_allclose(got[:, 1], ref[:, 1], rtol=0, atol=BATCH_ATOL)
    _cold["first"] = float(got[0, 1])

    assert summary["mode"] == "wallclock" and summary["links"] == "direct"
    assert summary["true_state"] is False
    diag = json.loads((out / "diagnostics.json").read_text())
    for i in (1, 2, 3):
        b = diag[f"bridge_{i}"]
        # every trial after the first started from a completed return, within tolerance
        assert b["return_timeouts"] == 0
        assert set(b["returns"]) == {str(k) for k in range(1, TRIALS + 1)}
        assert all(r["reached"] for r in b["returns"].values())
        shifts = np.array([b["initial_shifts"][str(k)] for k in range(TRIALS + 1)])
        print(f"bridge_{i} initial shifts (dx, dy, dtheta):", shifts.round(4).tolist())
        # tolerance 2 cm / 2 deg, measured on noisy (2 mm, 0.2 mrad) odometry
        assert (np.hypot(shifts[:, 0], shifts[:, 1]) <= 0.03).all()
        assert (np.abs(shifts[:, 2]) <= np.radians(2.5)).all()
        # no command clamped. Wall-clock time on a loaded machine: a sample instant
        # skipped, a command zeroed by the watchdog (the robot late), an odometry message
        # late, only where a process was starved past a sample, and rarely (the CI runs of
        # 27 Nov: 1 of 420 at a time, the learning still equal to batch above)
        # (and a fresh-clone CI of 7 Dec, the secure runs beside: 15 of 420 missed on one
        # bridge, the learning still equal to batch): at most 5 %
        rare = 0.05 * 140 * TRIALS
        assert b["clipped"] == 0, b["clipped"]
        for what in ("missed", "watchdog_zero", "stale_odometry"):
            assert b[what] <= rare, (what, b[what])
        # a command the robot sent so late that the bridge was already driving it back
        # ("a command while return": refused, as it must be; 1 each on two bridges in a
        # fresh-clone CI of 29 Nov), rarely; nothing else dropped
        dropped = dict(b["dropped"])
        assert dropped.pop("unexpected", 0) <= rare, b["dropped"]
        assert sum(dropped.values()) == 0, json.dumps(b.get("dropped_by_topic", b["dropped"]))
        # every sample of every trial was commanded, on direct links measured by eq. (11)
        r = diag[f"robot_{i}"]
        assert r["commands"] >= 0.97 * TRIALS * sc.samples, r["commands"]


def test_memory_learned_in_simulation_starts_the_robots_better(ros_env, tmp_path):
    """The paper's workflow: learn noise-free in simulation, carry the memory to the robots.
    The first trial on the (fake) robots from that memory has a smaller error than a cold
    start through the same stack. The robots' commands go through the safety filter (on by
    default on robots), so the memory is learned through it too: a memory learned without
    the base's acceleration limit asks for more than the robots may do."""
    sim = tmp_path / "sim"
    # learned through the filter as the robots run it: on the wall clock they hear each
    # other a sample late, and the filter allows for what a robot may have done since
    assert cli_main(["simulate", "paper-triangle3", "--trials", "100", "--no-noise",
                     "--no-delay", "--no-plots", "--safety", "--body", "p3dx",
                     "--safety-age", "0.2", "--out", str(sim)]) == 0
    memory = sim / "memory.npz"
    assert memory.is_file()
    out = tmp_path / "warm"
    res = launch(ros_env, out, *pioneer_args("--trials", "1", "--init-memory", str(memory)),
                 timeout=300)
    assert res.returncode == 0, res.stdout
    warm = float(read_metrics(out / "metrics.csv")[0, 1])
    if "first" not in _cold:  # run alone: a cold first trial through the stack
        cold_out = tmp_path / "cold"
        res = launch(ros_env, cold_out, *pioneer_args("--trials", "1"), timeout=300)
        assert res.returncode == 0, res.stdout
        _cold["first"] = float(read_metrics(cold_out / "metrics.csv")[0, 1])
    sim_last = float(read_metrics(sim / "metrics.csv")[-1, 1])
    # a robot node starved by the machine's load goes silent: its bridge zeroes the command
    # (watchdog_zero) or skips samples (missed), and the trial is not what the memory made it
    bridges = json.loads((out / "summary.json").read_text())["bridges"]
    starved = {b: (d["watchdog_zero"], d["missed"]) for b, d in bridges.items()
               if d["watchdog_zero"] or d["missed"]}
    print(f"first-trial max position error: cold {_cold['first']:.4f} m, warm {warm:.4f} m "
          f"(simulation's trial 99: {sim_last:.4f} m); bridges starved (zeroed, missed): "
          f"{starved or 'none'}")
    # measured with the earlier filter: cold 4.559 m, warm 0.280 m, simulation's trial 99
    # 0.255 m; a starved run (bridges zeroed 2-3 commands and missed 3-6 samples each, a
    # fresh-clone CI): 0.933 m
    assert warm < 0.25 * _cold["first"], (warm, _cold["first"], starved)
    if not starved:  # the memory's own start, undisturbed: what the simulation reached
        # (measured: warm 0.73 m against the simulation's 0.67 m before the barrier's two
        # gaps were mended, 2026-11-28; after, 0.77 and 0.80 m against 0.62 m: a receding
        # robot's credit now depends on a test of rates that the stack's pose ages, never
        # exactly the simulation's 0.2 s, can tip either way; docs/safety.md)
        assert warm < sim_last + 0.25, (warm, sim_last)


def test_a_memory_for_another_team_is_refused_before_anything_starts(ros_env, tmp_path):
    sim = tmp_path / "sim"
    assert cli_main(["simulate", "paper-hexagon6", "--trials", "1", "--no-plots", "--out",
                     str(sim)]) == 0
    res = launch(ros_env, tmp_path / "run",
                 *pioneer_args("--trials", "1", "--init-memory", str(sim / "memory.npz")),
                 timeout=120)
    assert res.returncode == 2
    assert "memory.npz: learned for another run" in res.stdout
    assert "6 robots, this run 3" in res.stdout


#: [s] from the stop's answer, every Twist on the graph is zero (issue 54)
STOP_WITHIN_S = 0.3


def test_stop_button_zeroes_every_command_and_ends_the_run(ros_env, tmp_path):
    """A Pioneer rehearsal stopped mid-trial by a plain Trigger call to /formation/stop:
    the call answers success; from 0.3 s after the answer every geometry_msgs/Twist on the
    graph (the robots' commands and the bridges' commands to the drivers) is zero; the run
    ends with status 7 and the console names the caller. The same run's /tf, taken by a
    plain rclpy subscriber, reaches every robot's base_link from map."""
    import rclpy
    from geometry_msgs.msg import Twist
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import String
    from std_srvs.srv import Trigger
    from tf2_msgs.msg import TFMessage

    import msgs_schema as ms

    out = tmp_path / "run"
    proc = start_launch(ros_env, out, *pioneer_args("--trials", "3", "--no-safety"))
    ctx = Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node("operator", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    twists: list[tuple[str, float, float, float]] = []  # topic, when, v, omega
    parents: dict[str, str] = {}
    started: list[float] = []
    every = QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT)
    topics = [f"/formation/robot_{i}/cmd_vel" for i in (1, 2, 3)] + [
        f"/pioneer_{i}/cmd_vel" for i in (1, 2, 3)]
    for topic in topics:
        node.create_subscription(Twist, topic, lambda m, t=topic: twists.append(
            (t, time.monotonic(), m.linear.x, m.angular.z)), every)
    for topic, qos in (("/tf", every), ("/tf_static", ms.TF_STATIC_READER_QOS)):
        node.create_subscription(TFMessage, topic, lambda m: parents.update(
            {tr.child_frame_id: tr.header.frame_id for tr in m.transforms}), qos)
    node.create_subscription(String, "/formation/leader/trial_events", lambda m: started.append(
        time.monotonic()) if '"start"' in m.data else None, 10)
    client = node.create_client(Trigger, "/formation/stop")
    try:
        deadline = time.monotonic() + 240
        # mid-trial: trial 0 started, and the bridges drive the robots since a second
        while time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.05)
            assert proc.poll() is None, proc.communicate()[0]
            if started and any(t.startswith("/pioneer") and when > started[0] + 1.0 and
                               (v, w) != (0.0, 0.0) for t, when, v, w in twists):
                break
        else:
            raise AssertionError("the trial did not start")
        assert client.wait_for_service(timeout_sec=10)
        asked = time.monotonic()
        future = client.call_async(Trigger.Request())
        while not future.done() and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.01)
        answered = time.monotonic()
        res = future.result()
        # until the launcher has stopped every process
        while proc.poll() is None and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.05)
        stdout = proc.communicate(timeout=30)[0]
    finally:
        stop_group(proc)
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    assert res is not None and res.success, res
    print(f"answer after {1e3 * (answered - asked):.1f} ms: {res.message}")
    late = [(t, when - answered, v, w) for t, when, v, w in twists
            if when >= answered + STOP_WITHIN_S]
    moving = [x for x in late if (x[2], x[3]) != (0.0, 0.0)]
    assert not moving, moving[:10]
    # the bridges went on commanding their drivers (zero) after the stop
    assert {t for t, *_ in late if t.startswith("/pioneer")} == set(topics[3:]), late
    for topic in topics[3:]:  # the first zero each driver got after the call
        first = min((when for t, when, v, w in twists if t == topic and when >= asked
                     and (v, w) == (0.0, 0.0)), default=None)
        assert first is not None, topic
        print(f"{topic}: zero {1e3 * (first - asked):.1f} ms after the call")
    assert proc.returncode == 7, stdout
    assert "stopped by /formation/stop called by /operator" in stdout, stdout
    # the live stack's frames, as a plain subscriber has them: one tree from map
    for i in (1, 2, 3):
        frame, chain = f"robot_{i}/base_link", []
        while frame in parents and len(chain) < 5:
            chain.append(frame)
            frame = parents[frame]
        assert (frame, chain) == ("map", [f"robot_{i}/base_link", f"robot_{i}/odom"]), parents
