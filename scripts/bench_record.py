#!/usr/bin/env python3
"""What recording costs: lockstep throughput of paper-hexagon6 (6 robot processes) with and
without `--record`, in each link mode, runs alternated so that drifts of the machine hit
both alike.

Prints samples per second (the simulator's own count over the time inside trials) and
per-sample latency for each run, the medians, and the cost of recording (target: at most
10 % of the throughput). Every run uses localhost discovery and its own ROS_DOMAIN_ID.

Usage: python scripts/bench_record.py [--trials 3] [--repeats 3] [--scenario paper-hexagon6]
                                      [--links emulated|direct|both]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path


def run(scenario: str, trials: int, out: Path, domain: int, record: bool, links: str) -> dict:
    argv = [sys.executable, "-m", "formation_ilc.cli", "launch", scenario, "--trials",
            str(trials), "--out", str(out), "--domain-id", str(domain), "--no-plots",
            "--links", links]
    if record:
        argv += ["--record", str(out / "run.mcap")]
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    res = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=900)
    if res.returncode != 0:
        raise SystemExit(f"launch failed:\n{res.stdout}\n{res.stderr}")
    summary = json.loads((out / "summary.json").read_text())
    tim = summary["timing"]
    size = (out / "run.mcap").stat().st_size if record else 0
    return {"samples_per_s": tim["samples_per_s"], "p50_ms": tim["p50_ms"],
            "p99_ms": tim["p99_ms"], "mcap_bytes": size}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="paper-hexagon6")
    ap.add_argument("--trials", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--links", choices=("emulated", "direct", "both"), default="both")
    args = ap.parse_args()
    modes = ["emulated", "direct"] if args.links == "both" else [args.links]
    res: dict[tuple[str, bool], list[dict]] = {(m, r): [] for m in modes for r in (0, 1)}
    dom = 40
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.repeats):
            for links in modes:
                for record in (False, True):
                    out = Path(tmp) / f"{i}-{links}-{int(record)}"
                    r = run(args.scenario, args.trials, out, dom, record, links)
                    dom = 40 + (dom - 39) % 50
                    res[(links, record)].append(r)
                    tag = f"{links:8s} {'record' if record else 'plain '}"
                    extra = f"  file {r['mcap_bytes'] / 1e6:.1f} MB" if record else ""
                    print(f"{tag} run {i + 1}: {r['samples_per_s']:7.1f} samples/s  p50 "
                          f"{r['p50_ms']:.2f} ms  p99 {r['p99_ms']:.2f} ms{extra}", flush=True)
    print(f"{args.scenario}, {args.trials} trials per run, lockstep, one process per robot, "
          f"median of {args.repeats}:")
    for links in modes:
        plain = statistics.median(r["samples_per_s"] for r in res[(links, False)])
        rec = statistics.median(r["samples_per_s"] for r in res[(links, True)])
        cost = 1 - rec / plain
        print(f"  {links} links: without recording {plain:.1f} samples/s, with recording "
              f"{rec:.1f} samples/s: recording costs {100 * cost:.1f} % (target <= 10 %) -> "
              f"{'MET' if cost <= 0.10 else 'MISSED'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
