"""Throughput of `formation-ilc sweep`: robot-samples per second on one core and on all
cores, parallel efficiency, the ratio to the per-core target, and the Dask cluster's overhead
per point against the local pool.

    nice -n 10 .venv/bin/python scripts/bench_sweep.py [--points 16] [--trials 300]
                                                       [--repeats 5] [--no-dask]

A robot-sample is one robot over one sample of one trial (the hexagon: 6 x 300 per trial).
Targets (issue 9): >= 8M robot-samples/s per core, parallel efficiency >= 90 % on this
machine's cores.

Every figure is given twice:

* wall: robot-samples / elapsed time. This is what a user waits for, but on a machine that
  other programs share it measures the cores that were free, not the sweep.
* CPU time: robot-samples / CPU seconds of every process of the sweep (this one, the pool's
  workers, or Dask's scheduler, nannies and workers, read from /proc), so the figure holds
  on a loaded machine. The CPU-time efficiency is the 1-process CPU per robot-sample over
  the N-process one: what running in parallel costs in extra work (the parent's scheduling,
  pickling, writing point files; shared caches and memory bandwidth), not the idle time.

Beside each phase: the CPU that other programs used meanwhile (from /proc/stat), in cores.
Only wall figures taken with that near 0 say what the machine can do; the script says so.

Phases (each sweep warm: its processes started and its kernels loaded by an untimed first
run; the median of --repeats timed runs is printed, and the best in brackets):

1. the kernel: `simulate()` of the sweep's points one after the other in this process
   (draws, trials, metrics; the scenarios loaded before), without the sweep around them;
2. a sweep of --points points (paper-hexagon6, two gains x points/2 seeds) in this process;
3. the same sweep on a pool of one process per core;
4. the same sweep on a local Dask cluster (one scheduler, one single-threaded worker per
   core, started here as separate processes); its table is compared with the pool's.

This script reports; no test checks times.
"""

from __future__ import annotations

import argparse
import os
import shutil
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from procstat import TICK, descendants, proc_cpu

from formation_ilc.config.scenario import load_scenario
from formation_ilc.model.simulate import simulate
from formation_ilc.studies.study import apply_fields
from formation_ilc.studies.sweep import close_pools, load_spec, run_sweep

SPEC = """\
scenario: paper-hexagon6
trials: {trials}
seeds: {{first: 1, count: {seeds}}}
check: false
grid:
  law.gain: [0.8, 1.2]
"""

TARGET_EFF = 0.90
TARGET_PER_CORE = 8e6


# --------------------------------------------------------------------------- measuring

def _machine_busy() -> float:
    """CPU seconds the whole machine has been busy (user, nice, system, irq, softirq)."""
    parts = Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]
    user, nice, system, _idle, _iowait, irq, softirq = (int(x) for x in parts[:7])
    return (user + nice + system + irq + softirq) / TICK


@dataclass
class Run:
    wall: float  # s
    cpu: float  # s, every process of the run
    others: float  # cores used by other programs meanwhile


def _measure(fn: Callable[[], object], roots: Callable[[], list[int]]) -> Run:
    """Run ``fn``; its wall time, the CPU of this process and of ``roots()``'s process
    trees (taken before and after: they must outlive the run), and the others' load."""
    pids = [p for p in descendants(roots()) if p != os.getpid()]
    c_children = sum(proc_cpu(p) or 0.0 for p in pids)
    busy0 = _machine_busy()
    c0 = time.process_time()
    t0 = time.perf_counter()
    fn()
    wall = time.perf_counter() - t0
    cpu = time.process_time() - c0
    cpu += sum(proc_cpu(p) or 0.0 for p in pids) - c_children
    others = max(0.0, (_machine_busy() - busy0 - cpu) / wall)
    return Run(wall, cpu, others)


def _runs(fn: Callable[[], object], repeats: int,
          roots: Callable[[], list[int]] = lambda: []) -> list[Run]:
    fn()  # warm: processes started, kernels loaded, scenarios parsed
    return [_measure(fn, roots) for _ in range(repeats)]


def _med(runs: list[Run], key: str) -> float:
    return statistics.median(getattr(r, key) for r in runs)


def _rate(work: float, runs: list[Run], key: str) -> float:
    return work / _med(runs, key)


def _line(label: str, work: float, runs: list[Run]) -> str:
    best_wall = work / min(r.wall for r in runs)
    best_cpu = work / min(r.cpu for r in runs)
    return (f"{label:<27s}{_rate(work, runs, 'wall') / 1e6:6.2f}M/s [{best_wall / 1e6:5.2f}M]"
            f"{_rate(work, runs, 'cpu') / 1e6:9.2f}M/s [{best_cpu / 1e6:5.2f}M] per core"
            f"{_med(runs, 'others'):7.2f} cores")


# --------------------------------------------------------------------------- the benchmark

def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _load() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=16, help="points per sweep (even; 16)")
    ap.add_argument("--trials", type=int, default=300, help="trials per point (300)")
    ap.add_argument("--repeats", type=int, default=5, help="timed runs per phase (5)")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                    help="processes of the pool and the Dask cluster (default: every core)")
    ap.add_argument("--no-dask", action="store_true", help="skip the Dask cluster")
    args = ap.parse_args()
    cores = args.workers
    tmp = Path(tempfile.mkdtemp(prefix="bench-sweep-"))
    procs: list[subprocess.Popen] = []
    try:
        spec_path = tmp / "spec.yaml"
        spec_path.write_text(SPEC.format(trials=args.trials, seeds=max(1, args.points // 2)))
        spec = load_spec(spec_path)
        n_points = len(spec.sim_tasks())
        sc = load_scenario("paper-hexagon6")
        rs_point = sc.n * sc.samples * args.trials
        total = rs_point * n_points
        print(f"machine: {os.cpu_count()} cores; load average before: {_load()}")
        print(f"sweep: paper-hexagon6, {n_points} points x {args.trials} trials = "
              f"{total / 1e6:.1f}M robot-samples; median of {args.repeats} warm runs [best]")
        print(f"{'robot-samples/s':<27s}{'  wall':<17s}{'      CPU time':<30s}  others used")

        # the sweep's points simulated one after the other, without the sweep around them
        points = [apply_fields(spec.scenario_text, t["fields"], seed=t["seed"],
                               trials=t["trials"]) for t in spec.sim_tasks()]
        for p in points:
            p.desired  # noqa: B018 - computed before timing, as a sweep's worker keeps it

        def kernel() -> None:
            for p in points:
                simulate(p)

        kern = _runs(kernel, args.repeats)
        print(_line("simulate() of the points", total, kern))

        def sweep(name: str, **kw: object) -> Callable[[], object]:
            def go() -> object:
                shutil.rmtree(tmp / name, ignore_errors=True)
                return run_sweep(spec, tmp / name, progress=False, keep_pool=True,
                                 **kw)  # type: ignore[arg-type]
            return go

        one = _runs(sweep("w1", workers=1), args.repeats)
        print(_line("sweep, 1 process", total, one))
        many = _runs(sweep("wn", workers=cores), args.repeats, roots=lambda: [os.getpid()])
        print(_line(f"sweep, {cores} processes", total, many))
        table = (tmp / "wn" / "results.csv").read_bytes()
        close_pools()

        r1_wall, rn_wall = _rate(total, one, "wall"), _rate(total, many, "wall")
        eff_wall = rn_wall / (cores * r1_wall)
        eff_cpu = _med(one, "cpu") / _med(many, "cpu")
        per_core_cpu = _rate(total, many, "cpu")
        print(f"parallel efficiency:      {100 * eff_wall:5.1f} % wall, "
              f"{100 * eff_cpu:5.1f} % CPU time  [target >= {100 * TARGET_EFF:.0f} %]")
        print(f"per core against 8M:      {_rate(total, one, 'cpu') / TARGET_PER_CORE:5.2f}x "
              f"(1 process, CPU time), {per_core_cpu / TARGET_PER_CORE:.2f}x ({cores} "
              f"processes, CPU time), {r1_wall / TARGET_PER_CORE:.2f}x (1 process, wall)")
        quiet = max(_med(r, "others") for r in (one, many))
        if quiet > 0.1:
            print(f"  note: other programs used up to {quiet:.2f} cores during the sweeps: "
                  f"the wall figures and the wall efficiency measure the free cores, not the "
                  f"sweep; run on a quiet machine for them")

        if not args.no_dask:
            try:
                from distributed import Client
            except ImportError:
                print("dask: not installed (pip install -e '.[cluster]'); skipped")
                return 0
            dask = Path(sys.executable).with_name("dask")
            port = _free_port()
            addr = f"tcp://127.0.0.1:{port}"
            log = (tmp / "dask.log").open("w")
            procs.append(subprocess.Popen([str(dask), "scheduler", "--host", "127.0.0.1",
                                           "--port", str(port), "--no-dashboard"],
                                          stdout=log, stderr=subprocess.STDOUT, cwd=tmp))
            procs.append(subprocess.Popen([str(dask), "worker", addr, "--host", "127.0.0.1",
                                           "--nworkers", str(cores), "--nthreads", "1",
                                           "--no-dashboard"],
                                          stdout=log, stderr=subprocess.STDOUT, cwd=tmp))
            with Client(addr, timeout=60) as client:
                client.wait_for_workers(cores, timeout=120)
            cluster = lambda: [p.pid for p in procs]  # noqa: E731

            def connect() -> None:
                with Client(addr, timeout=60):
                    pass

            conn = _runs(connect, args.repeats, roots=cluster)
            dk = _runs(sweep("dask", scheduler=addr), args.repeats, roots=cluster)
            # what the cluster's processes use doing nothing (heartbeats, monitors), in
            # cores: it accrues with time, not with points
            idle = _measure(lambda: time.sleep(3.0), cluster)
            idle_cores = idle.cpu / idle.wall
            print(_line(f"dask, {cores} workers", total, dk))
            same = (tmp / "dask" / "results.csv").read_bytes() == table
            wall_pp = 1000 * (_med(dk, "wall") - _med(many, "wall")) / n_points
            cpu_pp = 1000 * (_med(dk, "cpu") - _med(many, "cpu")) / n_points
            busy_pp = 1000 * (_med(dk, "cpu") - idle_cores * _med(dk, "wall")
                              - _med(conn, "cpu") - _med(many, "cpu")) / n_points
            print(f"dask overhead per point against the local pool: {wall_pp:+.2f} ms wall, "
                  f"{cpu_pp:+.2f} ms CPU (pool per point: "
                  f"{1000 * _med(many, 'wall') / n_points:.1f} ms wall, "
                  f"{1000 * _med(many, 'cpu') / n_points:.1f} ms CPU); table equal to the "
                  f"pool's: {same}")
            print(f"  of the CPU: the idle cluster's own {idle_cores:.3f} cores over the run, "
                  f"connecting once per sweep ({1000 * _med(conn, 'wall'):.0f} ms wall, "
                  f"{1000 * _med(conn, 'cpu'):.0f} ms CPU), and {busy_pp:+.2f} ms per point "
                  f"beyond both")
        print(f"load average after: {_load()}")
    finally:
        close_pools()
        for p in reversed(procs):
            p.terminate()
        for p in reversed(procs):
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
