"""Throughput of `formation-ilc sweep`: robot-samples per second on one core and on all
cores, parallel efficiency, and the Dask cluster's overhead per point against the local pool.

    .venv/bin/python scripts/bench_sweep.py [--points 16] [--trials 300] [--no-dask]

A robot-sample is one robot over one sample of one trial (the hexagon: 6 x 300 per trial).
Targets (issue 9): parallel efficiency >= 90 % on this machine's cores, >= 8M robot-samples/s
per core. The machine's load (``uptime``) is printed beside the figures: on a shared machine
they are only as good as the cores that were free. This script reports; no test checks
times.
"""

from __future__ import annotations

import argparse
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from formation_ilc.simulate import simulate  # noqa: E402
from formation_ilc.sweep import load_spec, run_sweep  # noqa: E402

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


def _load() -> str:
    return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()


def _sweep(spec_path: Path, out: Path, **kw: object) -> float:
    shutil.rmtree(out, ignore_errors=True)
    spec = load_spec(spec_path)
    t0 = time.perf_counter()
    run_sweep(spec, out, progress=False, **kw)  # type: ignore[arg-type]
    return time.perf_counter() - t0


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=16, help="points per sweep (even)")
    ap.add_argument("--trials", type=int, default=300)
    ap.add_argument("--no-dask", action="store_true", help="skip the Dask cluster")
    args = ap.parse_args()
    cores = os.cpu_count() or 1
    tmp = Path(tempfile.mkdtemp(prefix="bench-sweep-"))
    procs: list[subprocess.Popen] = []
    try:
        spec_path = tmp / "spec.yaml"
        spec_path.write_text(SPEC.format(trials=args.trials, seeds=max(1, args.points // 2)))
        spec = load_spec(spec_path)
        n_points = len(spec.sim_tasks())
        from formation_ilc.scenario import load_scenario

        sc = load_scenario("paper-hexagon6")
        rs_point = sc.n * sc.samples * args.trials
        total = rs_point * n_points
        print(f"load before: {_load()}")
        print(f"sweep: paper-hexagon6, {n_points} points x {args.trials} trials = "
              f"{total / 1e6:.1f}M robot-samples; {cores} cores")
        # the kernel alone, one run in this process (compiled before timing)
        simulate(sc.with_options(trials=2))
        t0 = time.perf_counter()
        simulate(sc.with_options(trials=args.trials))
        t_one = time.perf_counter() - t0
        unc = sc.uncertainty
        t0 = time.perf_counter()
        for k in range(args.trials):
            unc.draw_plant(1, k, sc.n, sc.samples)
            unc.draw_delays(1, k, sc.n, 1, sc.samples)
        t_draw = time.perf_counter() - t0
        print(f"one run in this process:   {rs_point / t_one / 1e6:6.2f}M robot-samples/s "
              f"({1000 * t_one / args.trials:.3f} ms/trial, of which drawing the trial's noise "
              f"and delays {1000 * t_draw / args.trials:.3f} ms)")
        t1 = _sweep(spec_path, tmp / "w1", workers=1)
        r1 = total / t1
        print(f"sweep, 1 process:          {r1 / 1e6:6.2f}M robot-samples/s ({t1:.2f} s) "
              f"[target >= {TARGET_PER_CORE / 1e6:.0f}M per core: "
              f"{'met' if r1 >= TARGET_PER_CORE else 'NOT met'}]")
        _sweep(spec_path, tmp / "wwarm", workers=cores, keep_pool=True)  # starts the pool
        tn = _sweep(spec_path, tmp / "wn", workers=cores)
        rn = total / tn
        eff = rn / (cores * r1)
        print(f"sweep, {cores} processes:        {rn / 1e6:6.2f}M robot-samples/s ({tn:.2f} s); "
              f"per core {rn / cores / 1e6:.2f}M; parallel efficiency {100 * eff:.0f} % "
              f"[target >= {100 * TARGET_EFF:.0f} %: {'met' if eff >= TARGET_EFF else 'NOT met'}]"
              )
        print("  (warm pool: its processes were started, and their kernels loaded, by a first "
              "sweep)")
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
                # warm the workers (imports, compiled kernels), as the local pool's
                # processes are not: the overhead below is per point, start-up excluded
                client.run(lambda: __import__("formation_ilc.simulate"))
            _sweep(spec_path, tmp / "dwarm", scheduler=addr)
            td = _sweep(spec_path, tmp / "dask", scheduler=addr)
            same = (tmp / "dask" / "results.csv").read_bytes() == (
                tmp / "wn" / "results.csv").read_bytes()
            print(f"dask, {cores} workers:          {total / td / 1e6:6.2f}M robot-samples/s "
                  f"({td:.2f} s, warm workers); table equal to the local pool's: {same}")
            print(f"dask overhead per point against the local pool: "
                  f"{1000 * (td - tn) / n_points:+.1f} ms (pool {1000 * tn / n_points:.1f} ms, "
                  f"dask {1000 * td / n_points:.1f} ms per point, wall time / points)")
        print(f"load after: {_load()}")
    finally:
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
