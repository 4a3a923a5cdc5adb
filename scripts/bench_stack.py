#!/usr/bin/env python3
"""Benchmark of the distributed stack: lockstep samples/s and per-sample latency.

Runs `formation-ilc launch` (real processes on localhost, own ROS_DOMAIN_ID each run) for
teams of 3, 6, 12 and 24 robots, with emulated and with direct links, one process per robot
and in container mode, and prints samples per second (simulated samples over the wall
time inside trials) and the latency of one sample (simulator publishes the poses -> every
robot's cmd_vel is in) p50/p90/p99.
Teams larger than the built-in scenarios are made from paper-hexagon6 by tiling it
(independent hexagons on one run, the same graph per copy).

The floor (on by default; ``--no-floor``): around each lockstep run, a trivial lockstep of the
same size on the same DDS, executor, QoS and discovery: a ticker process publishes a
PoseStamped to each of N responder processes, each answers with a Twist at once, and the
next tick goes out when all N answers are in (one round trip per tick, nothing else). Its
ticks/s, measured just before and just after each stack run, is what the machine's load
allows a lockstep at that moment; the stack's samples/s is printed as a ratio to the mean of
the two (direct / trivial, emulated / trivial). ``--repeat R`` runs every configuration R
times, alternated, and prints medians and ranges: on a machine shared with other work the
floor alone moved between 100 and 520 ticks/s within an hour.

    python scripts/bench_stack.py                 # all sizes, 3 trials each
    python scripts/bench_stack.py --sizes 6 24 --trials 2
    python scripts/bench_stack.py --links direct   # one link mode only
    python scripts/bench_stack.py --realtime 24   # only realtime: 24 robots, 1000 samples
    python scripts/bench_stack.py --sizes 6 --container 0 --repeat 5   # ratios to the floor

Realtime (``--realtime N``): one trial of 1000 samples at dT = 0.1 s (100 s of wall time),
one process per robot (``--rt-container C``: C robot nodes per process). Prints the missed
samples (a robot whose command was not in before the simulator's next tick), the command
arrival after the tick p50/p99/max, and how late the simulator's timer fired.

The scale curve (``--scale N ...``): for each team size, one launch of ``formation-ilc team
N`` (paper-hexagon6 for 6) in realtime at dT = 0.1 s (``--scale-mode lockstep`` for
lockstep), ``--scale-trials`` trials, one process per robot (``--scale-container C``: C
robots per process; ``--scale-hosts``: robots on network-namespace hosts;
``--scale-safety``: every robot through the safety filter; ``--fork-server``: the node
processes forked from one that imported them once). It prints, per
size: the time from the launch to the first trial's start (seen on the launcher's console),
discovery (when the launcher's monitor had found every node, and every node was ready),
the DDS participants, the resident memory (RSS) of every process at its peak, in all and
per kind of node, and its proportional memory (PSS: pages shared between processes counted
as each one's share), against a bare rclpy node (one publisher, one subscription, on the same
domain during the same run, so that it holds the same discovery data), the CPU of all the
run's processes per sample inside trials, and the realtime misses; then one table.

    python scripts/bench_stack.py --scale 6 12 24 50 100 --scale-trials 3
    python scripts/bench_stack.py --scale 50 --scale-trials 10 --links direct
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from formation_ilc.config.scenario import load_scenario


def team_scenario(n: int, tmp: Path, samples: int | None, dt: float | None = None) -> str:
    """A scenario file with n robots: paper-triangle3 for 3, hexagons tiled otherwise."""
    base = "paper-triangle3" if n == 3 else "paper-hexagon6"
    data = yaml.safe_load(load_scenario(base).text)
    if samples:
        data["samples"] = samples
    if dt:
        data["dt"] = dt
    if n not in (3, 6):
        if n % 6:
            raise SystemExit("sizes other than 3 must be multiples of 6")
        copies = n // 6
        g = data["graph"]
        leader = {}
        edges = []
        offsets = {}
        for c in range(copies):
            for r, w in g["leader"].items():
                leader[int(r) + 6 * c] = w
            for e in g["edges"]:
                ed = dict(e)
                ed["from"] = int(e["from"]) + 6 * c
                ed["to"] = int(e["to"]) + 6 * c
                edges.append(ed)
            for r, o in data["formation"]["offsets"].items():
                o2 = dict(o)
                if "x" in o2:
                    o2["x"] = float(o2["x"]) + 4.0 * c
                offsets[int(r) + 6 * c] = o2
        data["robots"] = n
        data["graph"] = dict(g, leader=leader, edges=edges)
        data["formation"]["offsets"] = offsets
        data["name"] = f"bench-{n}"
    path = tmp / f"team{n}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return str(path)


def run(scenario: str, trials: int, domain: int, container: int, mode: str, out: Path,
        timeout: float, links: str = "emulated") -> dict:
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    argv = [sys.executable, "-m", "formation_ilc.cli", "launch", scenario, "--trials",
            str(trials), "--out", str(out), "--domain-id", str(domain), "--no-plots",
            "--mode", mode, "--container", str(container), "--timeout", "60",
            "--links", links]
    t0 = time.perf_counter()
    res = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=timeout)
    wall = time.perf_counter() - t0
    if res.returncode:
        return {"error": (res.stdout + res.stderr)[-800:]}
    s = json.loads((out / "summary.json").read_text())
    s["wall"] = wall
    s["diagnostics"] = json.loads((out / "diagnostics.json").read_text())
    return s


# --------------------------------------------------------------------------- the floor

FLOOR_NS = "/bench_floor"


def _floor_node(role: str, index: int, n: int, ticks: int, warm: int) -> int:
    """One process of the trivial lockstep: the ticker (``index`` 0) or responder
    ``index`` (1..n). The ticker prints one JSON line (ticks, seconds, ticks_per_s,
    latency percentiles [ms]) and exits; a responder runs until SIGTERM."""
    import signal

    import rclpy
    from geometry_msgs.msg import PoseStamped, Twist
    from rclpy.node import Node
    from rclpy.signals import SignalHandlerOptions
    from rclpy.task import Future

    import msgs_schema as ms
    from formation_ilc.nodes.common import make_executor

    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    stop = Future()
    signal.signal(signal.SIGTERM, lambda *_: stop.done() or stop.set_result(0))
    node = Node(f"floor_{role}_{index}", namespace=FLOOR_NS)
    result: dict[str, float] = {}
    if role == "responder":
        answer = Twist()
        pub = node.create_publisher(Twist, f"answer_{index}", ms.SAMPLE_QOS)

        def subscribe() -> None:
            # take ticks only once the answers have their reader: none can be lost
            if pub.get_subscription_count() >= 1:
                gate.cancel()
                node.create_subscription(PoseStamped, f"tick_{index}",
                                         lambda m: pub.publish(answer), ms.SAMPLE_QOS)

        gate = node.create_timer(0.02, subscribe)
    else:
        tick = PoseStamped()
        tick.header.frame_id = ms.WORLD_FRAME
        pubs = [node.create_publisher(PoseStamped, f"tick_{r}", ms.SAMPLE_QOS)
                for r in range(1, n + 1)]
        state = {"t": -1, "pending": 0, "t0": 0.0, "sent": 0.0}
        lat: list[float] = []

        def send() -> None:
            state["t"] += 1
            if state["t"] == warm:
                state["t0"] = time.perf_counter()
            if state["t"] == warm + ticks:
                dt = time.perf_counter() - state["t0"]
                q = np.percentile(np.array(lat[warm:]) * 1e3, [50, 90, 99])
                result.update(ticks=ticks, seconds=dt, ticks_per_s=ticks / dt,
                              p50_ms=q[0], p90_ms=q[1], p99_ms=q[2])
                stop.set_result(0)
                return
            state["pending"] = n
            ms.ns_to_stamp(state["t"], tick.header.stamp)
            state["sent"] = time.perf_counter()
            for pub in pubs:
                pub.publish(tick)

        def on_answer(msg: Twist) -> None:
            state["pending"] -= 1
            if state["pending"] == 0:
                lat.append(time.perf_counter() - state["sent"])
                send()

        for r in range(1, n + 1):
            node.create_subscription(Twist, f"answer_{r}", on_answer, ms.SAMPLE_QOS)

        def start() -> None:
            if all(p.get_subscription_count() >= 1 for p in pubs):
                gate.cancel()
                send()

        gate = node.create_timer(0.02, start)
    ex = make_executor("events")
    ex.add_node(node)
    while rclpy.ok() and not stop.done():
        ex.spin_until_future_complete(stop, timeout_sec=0.25)
    node.destroy_node()
    rclpy.try_shutdown()
    if result:
        print(json.dumps(result), flush=True)
    return 0


def floor(n: int, domain: int, ticks: int, warm: int = 200, timeout: float = 300) -> dict:
    """The trivial lockstep of n responders (one process each) and a ticker, on ``domain``:
    {ticks, seconds, ticks_per_s, p50_ms, p90_ms, p99_ms} or {error}."""
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               ROS_DOMAIN_ID=str(domain), PYTHONUNBUFFERED="1")
    me = [sys.executable, str(Path(__file__).resolve()), "--floor-role"]
    common = ["--floor-n", str(n), "--floor-ticks", str(ticks), "--floor-warm", str(warm)]
    responders = [subprocess.Popen(me + ["responder", "--floor-index", str(r)] + common,
                                   env=env, stdout=subprocess.DEVNULL,
                                   stderr=subprocess.DEVNULL) for r in range(1, n + 1)]
    try:
        res = subprocess.run(me + ["ticker", "--floor-index", "0"] + common, env=env,
                             capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"error": "the floor's ticker timed out"}
    finally:
        for p in responders:
            p.terminate()
        for p in responders:
            try:
                p.wait(timeout=15)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
    lines = [ln for ln in res.stdout.splitlines() if ln.startswith("{")]
    if res.returncode or not lines:
        return {"error": (res.stdout + res.stderr)[-800:]}
    return json.loads(lines[-1])


def spread(values: list[float]) -> str:
    """median [min, max] of a list of figures."""
    if not values:
        return "-"
    return (f"{float(np.median(values)):7.2f} [{min(values):.2f}, {max(values):.2f}]"
            if len(values) > 1 else f"{values[0]:7.2f}")


def lockstep(n: int, args: argparse.Namespace, modes: list[str], tmp: Path, dom: int) -> int:
    """The lockstep runs of a team of n: the floor and each layout and link mode, ``repeat``
    times alternated; prints each run, then medians and ratios. Returns the next domain."""
    sc = team_scenario(n, tmp, None)
    layouts = [0, min(args.container, n)] if args.container else [0]
    rates: dict[tuple[int, str], list[float]] = {}
    ratios: dict[tuple[int, str], list[float]] = {}
    floors: list[float] = []
    def run_floor() -> float | None:
        nonlocal dom
        f = floor(n, dom, args.floor_ticks)
        dom = 30 + (dom - 29) % 71
        if "error" in f:
            print(f"{n:3d} processes, trivial lockstep: FAILED\n{f['error']}", flush=True)
            return None
        floors.append(f["ticks_per_s"])
        print(f"{n:3d} responders, trivial lockstep{'':19s} {f['ticks_per_s']:7.1f} ticks/s"
              f"    latency p50 {f['p50_ms']:6.2f} p90 {f['p90_ms']:6.2f} p99 "
              f"{f['p99_ms']:6.2f} ms", flush=True)
        return float(f["ticks_per_s"])

    # the machine's load moves within minutes: each run is bracketed by floor runs, and its
    # ratio is to the mean of the two
    before = run_floor() if args.floor else None
    for rnd in range(args.repeat):
        for cont in layouts:
            for links in modes:
                out = tmp / f"lock-{n}-{cont}-{links}-{rnd}"
                s = run(sc, args.trials, dom, cont, "lockstep", out, 900, links)
                dom = 30 + (dom - 29) % 71
                after = run_floor() if args.floor else None
                label = f"{n:3d} robots, {links:8s} " + (
                    f"container {cont}/process" if cont else "one process per robot")
                if "error" in s:
                    print(f"{label}: FAILED\n{s['error']}", flush=True)
                    before = after
                    continue
                t = s["timing"]
                rates.setdefault((cont, links), []).append(t["samples_per_s"])
                ratio = ""
                if before and after:
                    r = t["samples_per_s"] / (0.5 * (before + after))
                    ratios.setdefault((cont, links), []).append(r)
                    ratio = f"  {links} / trivial {r:.2f}"
                before = after
                print(f"{label:51s} {t['samples_per_s']:7.1f} samples/s  latency p50 "
                      f"{t['p50_ms']:6.2f} p90 {t['p90_ms']:6.2f} p99 {t['p99_ms']:6.2f} "
                      f"max {t['max_ms']:7.2f} ms  (wall {s['wall']:.1f} s incl. "
                      f"start-up){ratio}", flush=True)
    print(f"--- {n} robots, {args.repeat} round(s): median [min, max]", flush=True)
    if floors:
        print(f"{'trivial lockstep ticks/s':44s} {spread(floors)}", flush=True)
    targets = {"direct": 0.6, "emulated": 0.4}
    for cont in layouts:
        where = f"container {cont}/process" if cont else "one process per robot"
        for links in modes:
            if (cont, links) in rates:
                print(f"{links + ' samples/s, ' + where:44s} {spread(rates[(cont, links)])}",
                      flush=True)
        for links in modes:
            if (cont, links) in ratios:
                med = float(np.median(ratios[(cont, links)]))
                goal = targets[links]
                print(f"{links + ' / trivial, ' + where:44s} {spread(ratios[(cont, links)])}"
                      f"  (target >= {goal}) -> {'MET' if med >= goal else 'MISSED'}",
                      flush=True)
        d, e = rates.get((cont, "direct")), rates.get((cont, "emulated"))
        if d and e:
            r = float(np.median(d)) / float(np.median(e))
            print(f"{'direct / emulated (medians), ' + where:44s} {r:7.2f}", flush=True)
    return dom


# --------------------------------------------------------------------------- the curve

#: what each process is, from its command line (first match)
KINDS = (("fork server", b"formation_ilc.nodes.forkserver"),  # before the modules it names
         ("robot", b"formation_ilc.nodes.robot"), ("simulator", b"robot_sim.node"),
         ("link emulator", b"robot_sim.link_emulator"), ("leader", b"virtual_leader.node"),
         ("recorder", b"formation_ilc.nodes.recorder"), ("launcher", b"formation_ilc.cli"),
         ("bare node", b"--bare-node"))


def _proc_kb_mb(path: str, key: str) -> float | None:
    """The ``key:`` line of ``path`` (a /proc file giving kB) in MB, or None if the process
    is gone."""
    try:
        for line in Path(path).read_text().splitlines():
            if line.startswith(key):
                return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def rss_mb(pid: int) -> float | None:
    """Resident memory [MB] of ``pid`` (VmRSS), or None if it is gone."""
    return _proc_kb_mb(f"/proc/{pid}/status", "VmRSS:")


def pss_mb(pid: int) -> float | None:
    """Proportional memory [MB] of ``pid`` (Pss of /proc/PID/smaps_rollup: each page it
    maps shared with others counted as its share), or None if it is gone."""
    return _proc_kb_mb(f"/proc/{pid}/smaps_rollup", "Pss:")


def kind_of(pid: int) -> str | None:
    from procstat import cmdline

    cmd = cmdline(pid)
    for kind, mark in KINDS:
        if mark in cmd:
            return kind
    return None


def _bare_node(seconds: float) -> int:
    """A bare rclpy node: one publisher, one subscription, the EventsExecutor, spinning
    for ``seconds`` (the memory floor a node of the stack is compared with)."""
    import rclpy
    from geometry_msgs.msg import PoseStamped, Twist
    from rclpy.experimental import EventsExecutor

    rclpy.init()
    node = rclpy.create_node("bare_node", namespace="/bench_bare")
    node.create_publisher(Twist, "bare_out", 10)
    node.create_subscription(PoseStamped, "bare_in", lambda m: None, 10)
    ex = EventsExecutor()
    ex.add_node(node)
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        ex.spin_once(timeout_sec=0.25)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def scale_run(n: int, args: argparse.Namespace, tmp: Path, dom: int) -> dict:
    """One launch of a team of n for the curve; its figures, or {"error": ...}."""
    import threading

    from procstat import descendants, proc_cpu

    from formation_ilc.config.generate import team_yaml

    mode = args.scale_mode
    if n == 6:
        sc = "paper-hexagon6"
    else:
        path = tmp / f"team{n}.yaml"
        path.write_text(team_yaml(n))
        sc = str(path)
    out = tmp / f"scale-{n}-{mode}"
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               ROS_DOMAIN_ID=str(dom), PYTHONUNBUFFERED="1")
    from formation_ilc.nodes.forkserver import FORK_ENV

    env[FORK_ENV] = "1" if args.fork_server else "0"
    argv = [sys.executable, "-m", "formation_ilc.cli", "launch", sc, "--trials",
            str(args.scale_trials), "--out", str(out), "--domain-id", str(dom), "--no-plots",
            "--mode", mode, "--links", args.links if args.links != "both" else "emulated",
            "--container", str(args.scale_container)]
    if args.scale_hosts:
        argv += ["--hosts", "netns"]
    if args.scale_discovery:
        argv += ["--discovery", args.scale_discovery]
    if args.scale_dds_profile:
        argv += ["--dds-profile", args.scale_dds_profile]
    if args.scale_safety:
        argv += ["--safety"]
    t0 = time.monotonic()
    proc = subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    bare: subprocess.Popen[bytes] | None = None
    marks: dict[str, float] = {}
    lines: list[str] = []

    def read() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            now = time.monotonic() - t0
            lines.append(line.rstrip())
            if line.startswith("started ") and "started" not in marks:
                marks["started"] = now
            if line.startswith("start-up done") and "first" not in marks:
                marks["first"] = now
            if line.startswith("every trial is in") and "end" not in marks:
                marks["end"] = now

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    peak: dict[int, tuple[str, float]] = {}
    peak_pss: dict[int, float] = {}  # [MB] each process's largest PSS
    cpu_at: dict[str, dict[int, float]] = {}
    while proc.poll() is None and time.monotonic() - t0 < args.timeout:
        if bare is None and "started" in marks:
            # the bare node loads the run's Fast DDS profile too, if it has one (written
            # before the processes start), but not on hosts of their own: there it binds
            # the hub's address, which this namespace has not
            team = out / "fastdds-discovery.xml"
            own = team.exists() and not args.scale_hosts
            bare = subprocess.Popen(
                [sys.executable, str(Path(__file__).resolve()), "--bare-node",
                 str(args.timeout)],
                env={**env, **({"FASTRTPS_DEFAULT_PROFILES_FILE": str(team)}
                               if own else {})},
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        for pid in descendants([proc.pid] + ([bare.pid] if bare is not None else [])):
            kind = kind_of(pid)
            mb = rss_mb(pid)
            if kind is not None and mb is not None:
                peak[pid] = (kind, max(mb, peak.get(pid, (kind, 0.0))[1]))
                pss = pss_mb(pid)
                if pss is not None:
                    peak_pss[pid] = max(pss, peak_pss.get(pid, 0.0))
        for mark in ("first", "end"):  # the run's CPU when the trials start and end
            if mark in marks and mark not in cpu_at:
                cpu_at[mark] = {p: c for p in descendants([proc.pid])
                                if (c := proc_cpu(p)) is not None}
        time.sleep(0.5)
    if proc.poll() is None:
        proc.kill()
    proc.wait()
    if bare is not None:
        bare.terminate()
        bare.wait()
    reader.join(timeout=5)
    if proc.returncode:
        return {"error": "\n".join(lines[-12:])}
    s = json.loads((out / "summary.json").read_text())
    sim_diag = json.loads((out / "diagnostics.json").read_text()).get("robot_sim", {})
    by_kind: dict[str, list[float]] = {}
    for kind, mb in peak.values():
        by_kind.setdefault(kind, []).append(mb)
    pss_kind: dict[str, list[float]] = {}
    for pid, mb in peak_pss.items():
        pss_kind.setdefault(peak[pid][0], []).append(mb)
    samples = s["timing"].get("samples", 0)  # in every trial
    cpu = None
    cpu_kind: dict[str, list[float]] = {}  # ms per sample, per process of each kind
    if "first" in cpu_at and "end" in cpu_at:
        used = sum(cpu_at["end"].get(p, c) - c for p, c in cpu_at["first"].items())
        cpu = 1000.0 * used / max(1.0, samples)
        for p, c in cpu_at["first"].items():
            if p in peak:
                cpu_kind.setdefault(peak[p][0], []).append(
                    1000.0 * (cpu_at["end"].get(p, c) - c) / max(1.0, samples))
    startup = s.get("startup", {})
    # the CPU the processes had used by the first trial's start: what starting costs
    start_cpu = sorted(cpu_at.get("first", {}).values())
    return {"start_cpu": sum(start_cpu), "start_cpu_median": float(np.median(start_cpu))
            if start_cpu else float("nan"),
            # the bare node is no part; the fork server has no participant
            "robots": n, "participants": sum(k not in ("bare node", "fork server")
                                             for k, _ in peak.values()),
            "discovery": "server" if any(ln.startswith("discovery: through")
                                         for ln in lines) else "localhost",
            "first": marks.get("first"), "found": startup.get("all_found_s"),
            "ready": startup.get("all_ready_s"), "kinds": by_kind, "pss_kinds": pss_kind,
            "pss_total_mb": sum(mb for p, mb in peak_pss.items()
                                if peak[p][0] != "bare node"),
            "total_mb": sum(mb for k, mb in peak.values() if k != "bare node"),
            "cpu_ms": cpu, "samples": samples,
            "missed": s["timing"].get("missed_total", sum(s.get("missed", {}).values())),
            "robot_samples": n * samples, "timing": s["timing"],
            "missed_by": {k: v for k, v in s.get("missed", {}).items() if v},
            "missed_at": sim_diag.get("missed_at", {}),
            "cpu_kind": cpu_kind}


def _num(x: float | None, digits: int) -> str:
    """``x`` to ``digits`` decimals, or "n/a" for a figure the run did not give (a start-up
    too quick to be reported in steps leaves no time for every node found)."""
    return "n/a" if x is None else f"{x:.{digits}f}"


def scale_curve(args: argparse.Namespace, tmp: Path, dom: int) -> None:
    print(f"load before: {Path('/proc/loadavg').read_text().split()[:3]}"
          f"{'; safety filter on' if args.scale_safety else ''}"
          f"{'; fork server' if args.fork_server else ''}", flush=True)
    rows = []
    for n in args.scale:
        r = scale_run(n, args, tmp, dom)
        dom = 30 + (dom - 29) % 71
        if "error" in r:
            print(f"{n} robots: FAILED\n{r['error']}", flush=True)
            continue
        rows.append(r)
        bare = max(r["kinds"].get("bare node", [float("nan")]))
        print(f"{n} robots, {r['participants']} participants, discovery {r['discovery']}: "
              f"first trial "
              f"{_num(r['first'], 1)} s after the launch; every node found "
              f"{_num(r['found'], 1)} s, ready {_num(r['ready'], 1)} s (launcher's clock); "
              f"RSS in all {r['total_mb']:.0f} MB; CPU {_num(r['cpu_ms'], 2)} ms per "
              f"sample; missed {r['missed']} of {r['robot_samples']:.0f}", flush=True)
        t = r["timing"]
        if args.scale_mode == "realtime":
            worst = sorted(r["missed_by"].items(), key=lambda kv: -kv[1])[:8]
            print(f"  realtime: command arrival after the tick p50 {t.get('p50_ms', 0):.1f} "
                  f"p99 {t.get('p99_ms', 0):.1f} max {t.get('max_ms', 0):.1f} ms; timer lag "
                  f"p99 {t.get('tick_lag_p99_ms', 0):.1f} max {t.get('tick_lag_max_ms', 0):.1f} "
                  f"ms; missed by robot (most first) {dict(worst)}; by sample of a trial "
                  f"(most first) {r['missed_at']}", flush=True)
        # several of a kind (the robots): mean, median and max (before 2026-11-29 this
        # line printed the max and the median only, as "robot MAX (median M)")
        print("  CPU per sample in trials, per process [ms]: " + ", ".join(
            f"{k} {max(v):.2f}" if len(v) == 1 else
            f"{k} mean {float(np.mean(v)):.2f}, median {float(np.median(v)):.2f}, max "
            f"{max(v):.2f}" for k, v in sorted(r["cpu_kind"].items())), flush=True)
        print(f"  CPU used by the first trial's start: {r['start_cpu']:.1f} s in all, median "
              f"{r['start_cpu_median']:.2f} s per process", flush=True)
        print(f"  RSS, bare rclpy node {bare:.1f} MB; per kind, max [ratio to bare]: "
              + ", ".join(f"{k} {max(v):.1f} MB [{max(v) / bare:.2f}]"
                          for k, v in sorted(r["kinds"].items()) if k != "bare node"),
              flush=True)
        # PSS: a page shared by the processes that map it counted as each one's share (the
        # libraries every robot process loads are paid once between them, not once each)
        print(f"  PSS in all {r['pss_total_mb']:.0f} MB; per kind, median and max: "
              + ", ".join(f"{k} {float(np.median(v)):.1f} / {max(v):.1f} MB"
                          for k, v in sorted(r["pss_kinds"].items())), flush=True)
    print(f"load after: {Path('/proc/loadavg').read_text().split()[:3]}", flush=True)
    print(f"\n| robots | participants | launch to trial 1 [s] | all found / ready [s] | "
          f"RSS total [MB] | robot RSS / bare | robot PSS, median [MB] | CPU per sample [ms] | "
          f"{args.scale_mode} misses |\n| ---: | ---: | ---: | ---: | ---: | ---: | ---: | "
          f"---: | ---: |")
    for r in rows:
        bare = max(r["kinds"].get("bare node", [float("nan")]))
        robot = max(r["kinds"].get("robot", [float("nan")]))
        print(f"| {r['robots']} | {r['participants']} | {_num(r['first'], 1)} | "
              f"{_num(r['found'], 1)} / {_num(r['ready'], 1)} | {r['total_mb']:.0f} | "
              f"{robot / bare:.2f} | "
              f"{float(np.median(r['pss_kinds'].get('robot', [float('nan')]))):.1f} | "
              f"{_num(r['cpu_ms'], 2)} | {r['missed']} of "
              f"{r['robot_samples']:.0f} |", flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=int, nargs="*", default=None,
                    help="lockstep team sizes (default 3 6 12 24; none with --realtime)")
    ap.add_argument("--trials", type=int, default=3)
    ap.add_argument("--container", type=int, default=6,
                    help="robots per process in container mode (0: skip container runs)")
    ap.add_argument("--realtime", type=int, nargs="*", default=[],
                    help="team sizes to run in realtime mode (1000 samples at dT 0.1)")
    ap.add_argument("--rt-container", type=int, default=0, metavar="C",
                    help="realtime runs: C robot nodes per process (0: one per robot)")
    ap.add_argument("--rt-samples", type=int, default=1000)
    ap.add_argument("--rt-dt", type=float, default=0.1)
    ap.add_argument("--links", choices=("emulated", "direct", "both"), default="both",
                    help="link modes to run (default both, with the direct/emulated ratio)")
    ap.add_argument("--domain", type=int, default=30 + os.getpid() % 60)
    ap.add_argument("--no-floor", dest="floor", action="store_false",
                    help="skip the trivial lockstep (no ratios)")
    ap.add_argument("--floor-ticks", type=int, default=2000,
                    help="timed ticks of the trivial lockstep (after 200 warm-up ticks)")
    ap.add_argument("--repeat", type=int, default=1, metavar="R",
                    help="run the floor and every lockstep configuration R times, "
                         "alternated; print medians [min, max]")
    # one process of the trivial lockstep (started by this script)
    ap.add_argument("--floor-role", choices=("ticker", "responder"), help=argparse.SUPPRESS)
    ap.add_argument("--floor-index", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--floor-n", type=int, default=6, help=argparse.SUPPRESS)
    ap.add_argument("--floor-warm", type=int, default=200, help=argparse.SUPPRESS)
    ap.add_argument("--scale", type=int, nargs="*", default=[], metavar="N",
                    help="the scale curve: these team sizes (formation-ilc team N)")
    ap.add_argument("--scale-mode", choices=("realtime", "lockstep"), default="realtime")
    ap.add_argument("--scale-trials", type=int, default=3)
    ap.add_argument("--scale-container", type=int, default=0, metavar="C")
    ap.add_argument("--scale-hosts", action="store_true",
                    help="the curve's robots on network-namespace hosts (--hosts netns)")
    ap.add_argument("--scale-discovery", choices=("localhost", "server"), default=None,
                    help="the curve's launches with --discovery this (default: the "
                         "launcher's, the discovery server from 64 participants)")
    ap.add_argument("--scale-dds-profile", choices=("lossy", "none"), default=None,
                    help="with --scale-hosts: the launches' --dds-profile (default: the "
                         "launcher's, lossy)")
    ap.add_argument("--scale-safety", action="store_true",
                    help="the curve's robots through the safety filter (--safety: each "
                         "reads the whole team's poses every sample)")
    ap.add_argument("--fork-server", action="store_true",
                    help="the curve's launches fork their node processes from one server "
                         "that imported them once (FORMATION_ILC_FORKSERVER=1)")
    ap.add_argument("--timeout", type=float, default=3600.0,
                    help="[s] the longest one launch of the curve may take")
    ap.add_argument("--bare-node", type=float, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.bare_node is not None:
        return _bare_node(args.bare_node)
    if args.floor_role:
        return _floor_node(args.floor_role, args.floor_index, args.floor_n, args.floor_ticks,
                           args.floor_warm)
    if args.sizes is None:
        args.sizes = [] if args.realtime or args.scale else [3, 6, 12, 24]
    modes = ["emulated", "direct"] if args.links == "both" else [args.links]
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        dom = args.domain
        if args.scale:
            scale_curve(args, tmp, dom)
            dom = 30 + (dom - 29 + len(args.scale)) % 71
        for n in args.sizes:
            dom = lockstep(n, args, modes, tmp, dom)
        for n in args.realtime:
            # 1000 samples at dT = 0.1 s in realtime: 100 s of wall time
            sc = team_scenario(n, tmp, args.rt_samples, args.rt_dt)
            out = tmp / f"rt-{n}"
            s = run(sc, 1, dom, args.rt_container, "realtime", out, 900, modes[0])
            dom = 30 + (dom - 29) % 71
            layout = (f"container {args.rt_container}/process" if args.rt_container
                      else "one process per robot")
            if "error" in s:
                print(f"realtime {n} robots: FAILED\n{s['error']}")
                continue
            t = s["timing"]
            missed = {r: c for r, c in s.get("missed", {}).items() if c}
            print(f"realtime {n} robots ({layout}), {t['samples']} samples at dT "
                  f"{args.rt_dt} s: missed {sum(missed.values())} of "
                  f"{n * t['samples']} robot-samples {missed or ''}\n"
                  f"  command arrival after the tick p50 {t['p50_ms']:.2f} p90 "
                  f"{t['p90_ms']:.2f} p99 {t['p99_ms']:.2f} max {t['max_ms']:.2f} ms; "
                  f"all {n} in p50 {t['all_in_p50_ms']:.2f} p99 {t['all_in_p99_ms']:.2f} ms; "
                  f"timer lag p99 {t['tick_lag_p99_ms']:.2f} max {t['tick_lag_max_ms']:.2f} "
                  f"ms; superseded {t['superseded']}", flush=True)
            d = s["diagnostics"]
            late_links = sum(d.get("link_emulator", {}).get("late", {}).values())
            late_robots = sum(v.get("late", {}).get("links", 0) for k, v in d.items()
                              if k.startswith("robot_") and k != "robot_sim")
            print(f"  {modes[0]} links: deliveries late at the link emulator {late_links}, "
                  f"samples a robot commanded before its links were in {late_robots}",
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
