#!/usr/bin/env python3
"""The floor of a robot's CPU per sample: rclpy processes that do a robot's DDS work and
nothing else, at dT = 0.1 s, one process per robot (issue 41's target: 0.6 ms a
robot-sample at 50 robots).

A plant process publishes, every 100 ms on a wall timer, each robot's pose (bytes of a
PoseStamped on ``robot_<i>/pose``) and the leader's reference (``leader/reference``), and
reads every ``cmd_vel``. Each of N robot processes does, with the stack's topics, QoS
(``msgs_schema``), raw takes and publishes and the EventsExecutor spun in slices as
``nodes.common.spin_main`` does, one of these patterns:

* ``idle``: a node with the ``cmd_vel`` publisher only, spinning: 0 in, 0 out (what a
  process of the run costs with no message of its own: discovery, the spin slices).
* ``minimal``: takes its pose, publishes a Twist (the bytes) at once: 1 in, 1 out.
* ``robot0``: what a robot of ``formation-ilc team N`` did per sample in realtime with
  direct links and the clock exchange on, counted from ``nodes/robot.py``,
  ``nodes/clocks.py`` and ``nodes/common.py``: takes its pose and its one in-link (its
  in-neighbour's ``shared_pose``, or the leader's reference); publishes its pose on
  ``shared_pose`` when it has out-neighbours; commands when both are in (the deadline
  timer reset at the pose and cancelled at the command; it fires when a link is late);
  a 10 Hz clock timer that asks its in-neighbour's clock (or the leader's) 2 times a
  second and reads every answer on that clock's answer topic (the plant answers for the
  leader); answers its out-neighbours' questions; the 1 Hz ``/diagnostics`` stream
  (``nodes.common.Diagnostics``); a 4 Hz steady timer (the checked subscriptions' poll
  of the trajectories) with nothing to do; spun in 0.25 s slices. No learner, no law, no
  message is decoded beyond a pose's bytes being handed on: the robot before issue 41's
  cuts (2026-11-29).
* ``robot``: the same as the robot does since: the clock timer at 2 Hz, the deadline
  armed only when a link is not in at the pose, no re-check inside a trial, spun in the
  node's slices (``nodes.common.SPIN_SLICE``; the figures in the docs: 1 s).

Every robot process's CPU (user + system, ``/proc``: ``scripts/procstat.py``) is read over
``--seconds`` after every process matched its topics and ``--warm`` seconds ran; it prints
per pattern the CPU per robot-sample (mean, median, min, max), the commands the plant
received per robot and tick in that window (about 1: the pattern ran), the ratio of the
median to the 0.6 ms target, and the load average before and after.

    python scripts/bench_floor.py                     # 50 robots, every pattern
    python scripts/bench_floor.py --robots 50 --patterns robot --seconds 30
    python scripts/bench_floor.py --patterns minimal --best-effort   # per-sample topics
                                                                   # best effort

Run it in a network namespace of its own (the ROS processes' discovery stays there).
"""

from __future__ import annotations

import argparse
import json
import os
import select
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

#: issue 41's target [ms] of CPU per robot-sample at 50 robots
TARGET_MS = 0.6
DT = 0.1
NS = "/bench_floor"
#: the per-sample topics' QoS: msgs_schema's SAMPLE_QOS, or (``--best-effort``) the same
#: best effort, to price a reliable writer's per-sample work
_QOS: list = []


def _sample_qos(best_effort: bool) -> object:
    import copy

    from rclpy.qos import ReliabilityPolicy

    import msgs_schema as ms

    qos = copy.copy(ms.SAMPLE_QOS)
    if best_effort:
        qos.reliability = ReliabilityPolicy.BEST_EFFORT
    return qos


def team_graph(n: int) -> tuple[list[int], list[list[int]]]:
    """(the in-link of each robot, 0-based: -1 the leader; the out-neighbours of each)
    of ``formation-ilc team n``."""
    from formation_ilc.config.generate import team_yaml
    from formation_ilc.config.scenario import load_scenario
    from formation_ilc.model.simulate import Problem

    with tempfile.NamedTemporaryFile("w", suffix=".yaml", delete=False) as f:
        f.write(team_yaml(n))
    try:
        pb = Problem.from_scenario(load_scenario(f.name))
    finally:
        os.unlink(f.name)
    src = [int(pb.src[i][0]) for i in range(n)]  # one in-link each in team N
    if any(len(pb.src[i]) != 1 for i in range(n)):
        raise SystemExit("the floor models one in-link per robot (formation-ilc team N)")
    outs = [[r for r in range(n) if src[r] == i] for i in range(n)]
    return src, outs


def _spin(node: object, stop: object, slice_s: float | None = None) -> None:
    import rclpy

    from formation_ilc.nodes.common import SPIN_SLICE, make_executor

    ex = make_executor("events")
    ex.add_node(node)
    while rclpy.ok() and not stop.done():  # type: ignore[attr-defined]
        # as spin_main does
        ex.spin_until_future_complete(stop, timeout_sec=slice_s or SPIN_SLICE)


def plant(n: int, src: list[int], pattern: str) -> int:
    """Poses at 10 Hz, the reference, the leader's clock answers; counts commands and
    prints them with its ticks as one JSON line on SIGUSR1. Says ``matched`` on stdout
    once every robot's endpoints are."""
    import rclpy
    from geometry_msgs.msg import PoseStamped, Twist
    from rclpy.node import Node
    from rclpy.signals import SignalHandlerOptions
    from rclpy.task import Future
    from sensor_msgs.msg import TimeReference

    import msgs_schema as ms
    from formation_ilc.protocol import wire

    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    stop = Future()
    signal.signal(signal.SIGTERM, lambda *_: stop.done() or stop.set_result(0))
    node = Node("floor_plant", namespace=NS)
    pose_pubs = [node.create_publisher(PoseStamped, ms.pose_topic(i + 1), _QOS[0])
                 for i in range(n)]
    ref_pub = node.create_publisher(PoseStamped, ms.REFERENCE, _QOS[0])
    counts = [0] * n

    def on_cmd(i: int) -> object:
        def cb(_: object) -> None:
            counts[i] += 1
        return cb

    cmd_subs = [node.create_subscription(Twist, ms.cmd_vel_topic(i + 1), on_cmd(i),
                                         _QOS[0], raw=True) for i in range(n)]
    askers = [i for i in range(n) if src[i] < 0]
    pong = node.create_publisher(TimeReference, ms.clock_pong_topic(ms.LEADER_NODE),
                                 ms.CLOCK_SYNC_QOS)

    def on_ping(data: bytes, asker: str) -> None:
        t2 = time.time_ns()
        asked, seq, _ = ms.read_ping(data)
        if asked == ms.LEADER_NODE:
            pong.publish(ms.pong_msg(seq, t2, time.time_ns(), asker))

    for i in askers:
        name = ms.robot_name(i + 1)
        node.create_subscription(TimeReference, ms.clock_ping_topic(name),
                                 lambda m, a=name: on_ping(m, a), ms.CLOCK_SYNC_QOS, raw=True)
    state = {"k": 0, "matched": False}

    def tick() -> None:
        if not state["matched"]:
            if ((pattern == "idle"
                 or all(p.get_subscription_count() >= 1 for p in pose_pubs))
                    and all(s.get_publisher_count() >= 1 for s in cmd_subs)
                    and (not pattern.startswith("robot")
                         or ref_pub.get_subscription_count() >= len(askers))):
                state["matched"] = True
                print("matched", flush=True)
        k = state["k"] = state["k"] + 1
        t = k * int(DT * 1e9)
        ref_pub.publish(wire.pose_bytes((0.0, 0.0, 0.0), t))
        for i, p in enumerate(pose_pubs):
            p.publish(wire.pose_bytes((float(i), 0.0, 0.0), t))

    node.create_timer(DT, tick)
    # SIGUSR1: the commands and ticks so far, one JSON line (the window's bounds)
    signal.signal(signal.SIGUSR1, lambda *_: print(
        json.dumps({"commands": sum(counts), "ticks": state["k"]}), flush=True))
    _spin(node, stop)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def robot(i: int, pattern: str, src: list[int], outs: list[list[int]]) -> int:
    """Robot ``i`` (0-based) of the floor, until SIGTERM."""
    import rclpy
    from geometry_msgs.msg import PoseStamped, Twist
    from rclpy.clock import Clock, ClockType
    from rclpy.node import Node
    from rclpy.signals import SignalHandlerOptions
    from rclpy.task import Future
    from sensor_msgs.msg import TimeReference

    import msgs_schema as ms
    from formation_ilc.nodes.common import Diagnostics
    from formation_ilc.protocol import wire

    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    stop = Future()
    signal.signal(signal.SIGTERM, lambda *_: stop.done() or stop.set_result(0))
    me = ms.robot_name(i + 1)
    node = Node(me, namespace=NS)
    cmd_pub = node.create_publisher(Twist, ms.cmd_vel_topic(i + 1), _QOS[0])
    cmd = wire.twist_bytes((0.1, 0.0))
    if pattern in ("idle", "minimal"):
        if pattern == "minimal":
            node.create_subscription(PoseStamped, ms.pose_topic(i + 1),
                                     lambda m: cmd_pub.publish(cmd), _QOS[0],
                                     raw=True)
        _spin(node, stop)
        node.destroy_node()
        rclpy.try_shutdown()
        return 0

    steady = Clock(clock_type=ClockType.STEADY_TIME)
    before = pattern == "robot0"  # the robot before issue 41's cuts
    st = {"pose": False, "link": False, "done": False}
    shared = (node.create_publisher(PoseStamped, ms.shared_pose_topic(i + 1), _QOS[0])
              if outs[i] else None)

    def command() -> None:
        st["done"] = True
        cmd_pub.publish(cmd)
        deadline.cancel()

    def on_pose(data: bytes) -> None:
        wire.read_pose(data)
        st["pose"], st["done"] = True, False
        if shared is not None and shared.get_subscription_count():
            shared.publish(data)
        if st["link"]:
            if before:
                deadline.reset()
            st["pose"] = st["link"] = False
            command()
        else:
            deadline.reset()

    def on_link(data: bytes) -> None:
        wire.read_pose(data)
        st["link"] = True
        if st["pose"] and not st["done"]:
            st["pose"] = st["link"] = False
            command()

    def on_deadline() -> None:
        deadline.cancel()
        if not st["done"]:
            command()

    deadline = node.create_timer(0.75 * DT, on_deadline)
    deadline.cancel()
    node.create_subscription(PoseStamped, ms.pose_topic(i + 1), on_pose, _QOS[0],
                             raw=True)
    j = src[i]
    node.create_subscription(PoseStamped, ms.REFERENCE if j < 0
                             else ms.shared_pose_topic(j + 1), on_link, _QOS[0],
                             raw=True)
    # the clock exchange: questions to the in-link's clock, answers to the out-neighbours
    peer = ms.LEADER_NODE if j < 0 else ms.robot_name(j + 1)
    ping = node.create_publisher(TimeReference, ms.clock_ping_topic(me), ms.CLOCK_SYNC_QOS)

    def on_pong(data: bytes) -> None:
        ms.read_pong(data)

    node.create_subscription(TimeReference, ms.clock_pong_topic(peer), on_pong,
                             ms.CLOCK_SYNC_QOS, raw=True)
    clock = {"n": 0}

    def on_clock() -> None:
        clock["n"] += 1
        if not before or clock["n"] % 5 == 0:  # 2 questions a second (PING_HZ)
            ping.publish(ms.ping_msg(clock["n"], time.time_ns(), peer))

    # protocol.timesync.BURST_HZ before; the question rate PING_HZ since (nodes.clocks)
    node.create_timer(DT if before else 5 * DT, on_clock)
    if outs[i]:
        pong = node.create_publisher(TimeReference, ms.clock_pong_topic(me),
                                     ms.CLOCK_SYNC_QOS)

        def on_ping(data: bytes, asker: str) -> None:
            t2 = time.time_ns()
            asked, seq, _ = ms.read_ping(data)
            if asked == me:
                pong.publish(ms.pong_msg(seq, t2, time.time_ns(), asker))

        for r in outs[i]:
            a = ms.robot_name(r + 1)
            node.create_subscription(TimeReference, ms.clock_ping_topic(a),
                                     lambda m, a=a: on_ping(m, a), ms.CLOCK_SYNC_QOS,
                                     raw=True)
    Diagnostics(node)  # the 1 Hz standard stream
    if before:  # the checked subscriptions' poll; since, it sleeps inside a trial
        node.create_timer(0.25, lambda: None, clock=steady)
    _spin(node, stop, 0.25 if before else None)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def load() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


def measure(n: int, pattern: str, args: argparse.Namespace, tmp: Path) -> dict:
    """One floor run: {pattern, per_robot_ms [...], commands_per_sample, load_before, ...}."""
    from procstat import proc_cpu

    from formation_ilc.system.discovery import needs_peers, peers_profile

    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               ROS_DOMAIN_ID=str(args.domain), PYTHONUNBUFFERED="1")
    if needs_peers(n + 1):
        prof = tmp / "fastdds-discovery.xml"
        prof.write_text(peers_profile(None, args.domain, n + 1))
        env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(prof)
    me = [sys.executable, str(Path(__file__).resolve()), "--robots", str(n),
          *(["--best-effort"] if args.best_effort else [])]
    out: dict = {"pattern": pattern + (" best effort" if args.best_effort else ""),
                 "robots": n, "load_before": load()}
    robots = [subprocess.Popen(me + ["--role", "robot", "--index", str(i), "--patterns",
                                     pattern], env=env, stdout=subprocess.DEVNULL)
              for i in range(n)]
    pl = subprocess.Popen(me + ["--role", "plant", "--patterns", pattern], env=env,
                          stdout=subprocess.PIPE, text=True)
    try:
        assert pl.stdout is not None
        t0 = time.monotonic()
        if not select.select([pl.stdout], [], [], args.match_timeout)[0]:
            return {**out, "error": f"not matched in {args.match_timeout:.0f} s"}
        line = pl.stdout.readline()
        if line.strip() != "matched":
            return {**out, "error": f"the plant said {line!r}"}
        out["matched_s"] = time.monotonic() - t0
        time.sleep(args.warm)

        def mark() -> dict:
            pl.send_signal(signal.SIGUSR1)
            assert pl.stdout is not None
            return json.loads(pl.stdout.readline())

        m0 = mark()
        c0 = {p.pid: proc_cpu(p.pid) for p in robots}
        w0 = time.monotonic()
        time.sleep(args.seconds)
        c1 = {p.pid: proc_cpu(p.pid) for p in robots}
        window = time.monotonic() - w0
        m1 = mark()
    finally:
        pl.send_signal(signal.SIGTERM)
        try:
            pl.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            pl.kill()
            pl.communicate()
        for p in robots:
            p.terminate()
        for p in robots:
            try:
                p.wait(timeout=15)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
    samples = window / DT
    per = [1000.0 * (c1[p] - c0[p]) / samples for p in c0
           if c0[p] is not None and c1[p] is not None]
    cmds = m1["commands"] - m0["commands"]
    ticks = m1["ticks"] - m0["ticks"]
    out.update(per_robot_ms=per, samples=samples, load_after=load(), commands=cmds,
               ticks=ticks, commands_per_sample=cmds / max(1, n * ticks))
    return out


def report(r: dict) -> None:
    per = r["per_robot_ms"]
    med = statistics.median(per)
    print(f"{r['robots']} robots, pattern {r['pattern']}: CPU per robot-sample mean "
          f"{statistics.fmean(per):.3f} ms, median {med:.3f} ms (min {min(per):.3f}, max "
          f"{max(per):.3f}) over {r['samples']:.0f} samples; the plant's {r['ticks']} ticks in "
          f"that window had {r['commands']} commands ({r['commands_per_sample']:.3f} per "
          f"robot-tick); median / target "
          f"{TARGET_MS} ms = {med / TARGET_MS:.2f}; matched after {r['matched_s']:.1f} s; "
          f"load before {r['load_before']}, after {r['load_after']}", flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robots", type=int, default=50)
    ap.add_argument("--patterns", nargs="+", choices=("idle", "minimal", "robot0", "robot"),
                    default=["idle", "minimal", "robot0", "robot"])
    ap.add_argument("--seconds", type=float, default=30.0,
                    help="the CPU window [s] (default 30: 300 samples)")
    ap.add_argument("--warm", type=float, default=5.0,
                    help="[s] after every endpoint matched, before the window")
    ap.add_argument("--match-timeout", type=float, default=180.0,
                    help="[s] to wait for every endpoint to match")
    ap.add_argument("--domain", type=int, default=30 + os.getpid() % 60)
    ap.add_argument("--best-effort", action="store_true",
                    help="the per-sample topics best effort (the stack's are reliable)")
    ap.add_argument("--role", choices=("plant", "robot"), help=argparse.SUPPRESS)
    ap.add_argument("--index", type=int, default=0, help=argparse.SUPPRESS)
    args = ap.parse_args()
    _QOS.append(_sample_qos(args.best_effort))
    if args.role:
        src, outs = team_graph(args.robots)
        if args.role == "plant":
            return plant(args.robots, src, args.patterns[0])
        return robot(args.index, args.patterns[0], src, outs)
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_floor_") as tmp:
        for pattern in args.patterns:
            r = measure(args.robots, pattern, args, Path(tmp))
            if "error" in r:
                print(f"{pattern}: FAILED: {r['error']}", flush=True)
                continue
            report(r)
            rows.append(r)
    print(f"\n| pattern | robots | CPU per robot-sample, mean (median) [ms] | median / "
          f"{TARGET_MS} ms | load before / after |\n| --- | ---: | ---: | ---: | --- |")
    for r in rows:
        per = r["per_robot_ms"]
        print(f"| {r['pattern']} | {r['robots']} | {statistics.fmean(per):.3f} "
              f"({statistics.median(per):.3f}) | {statistics.median(per) / TARGET_MS:.2f} | "
              f"{r['load_before']} / {r['load_after']} |")
    return 0 if rows else 1


if __name__ == "__main__":
    sys.exit(main())
