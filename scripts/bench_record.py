#!/usr/bin/env python3
"""What recording costs: lockstep throughput of paper-hexagon6 (6 robot processes) with and
without `--record`, in each link mode, runs alternated so that drifts of the machine hit
both alike.

Prints samples per second (the simulator's own count over the time inside trials) and
per-sample latency for each run, the medians, and the cost of recording (target: at most
10 % of the throughput). Every run uses localhost discovery and its own ROS_DOMAIN_ID.

Usage: python scripts/bench_record.py [--trials 3] [--repeats 3] [--scenario paper-hexagon6]
                                      [--links emulated|direct|both]
       python scripts/bench_record.py --chunks [16384 65536 262144 1048576] [--trials 3]

``--chunks``: the recorder's chunk size limit, traded against damage. One recorded launch,
rewritten as the recorder would write it (a chunk ends at the size limit or 0.5 s of log
time) at each size: file size, chunks, messages per chunk (what one damaged chunk loses)
and the CPU time of writing; then launches recorded at the smallest and largest size,
alternated, for the throughput cost.
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


def run(scenario: str, trials: int, out: Path, domain: int, record: bool, links: str,
        chunk: int | None = None) -> dict:
    argv = [sys.executable, "-m", "formation_ilc.cli", "launch", scenario, "--trials",
            str(trials), "--out", str(out), "--domain-id", str(domain), "--no-plots",
            "--links", links]
    if record:
        argv += ["--record", str(out / "run.mcap")]
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    if chunk is not None:
        env["FORMATION_ILC_RECORDER_CHUNK_BYTES"] = str(chunk)
    res = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=900)
    if res.returncode != 0:
        raise SystemExit(f"launch failed:\n{res.stdout}\n{res.stderr}")
    summary = json.loads((out / "summary.json").read_text())
    tim = summary["timing"]
    size = (out / "run.mcap").stat().st_size if record else 0
    return {"samples_per_s": tim["samples_per_s"], "p50_ms": tim["p50_ms"],
            "p99_ms": tim["p99_ms"], "mcap_bytes": size}


def rewrite(src: Path, dst: Path, chunk: int, period_ns: int = 500_000_000) -> dict:
    """``src`` written again as the recorder writes it with chunks of at most ``chunk``
    bytes, a chunk also ending every ``period_ns`` of log time (its flush timer)."""
    import time

    from mcap.reader import make_reader

    from formation_ilc.recordings.mcap_io import RosMcapWriter, read_messages

    with src.open("rb") as fh:
        summary = make_reader(fh).get_summary()
    chans = {c.topic: (summary.schemas[c.schema_id].name,
                       c.metadata.get("offered_qos_profiles", "")) for c in
             summary.channels.values()}
    msgs = list(read_messages(src))
    t0 = time.process_time()
    w = RosMcapWriter(dst, flush_period=0, chunk_size=chunk)
    for topic, (typ, qos) in chans.items():
        w.channel(topic, typ, qos)
    last = msgs[0].log_time if msgs else 0
    for m in msgs:
        if m.log_time - last >= period_ns:
            w.flush()
            last = m.log_time
        w.write(m.topic, m.data, m.log_time, m.publish_time)
    w.close()
    cpu = time.process_time() - t0
    with dst.open("rb") as fh:
        st = make_reader(fh).get_summary().statistics
    return {"bytes": dst.stat().st_size, "chunks": st.chunk_count, "messages": len(msgs),
            "cpu_us_per_msg": 1e6 * cpu / max(len(msgs), 1)}


def bench_chunks(args: argparse.Namespace) -> int:
    sizes = sorted(args.chunks or [16384, 65536, 262144, 1048576])
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "base"
        run(args.scenario, args.trials, out, 40, True, "emulated", chunk=max(sizes))
        src = out / "run.mcap"
        print(f"{args.scenario}, {args.trials} trials, emulated links, recorded and "
              f"rewritten per chunk size:")
        print(f"{'chunk limit':>12s} {'file MB':>8s} {'chunks':>7s} {'msgs/chunk':>11s} "
              f"{'write us/msg':>13s}")
        for size in sizes:
            r = rewrite(src, Path(tmp) / f"{size}.mcap", size)
            print(f"{size:12d} {r['bytes'] / 1e6:8.3f} {r['chunks']:7d} "
                  f"{r['messages'] / max(r['chunks'], 1):11.0f} {r['cpu_us_per_msg']:13.2f}",
                  flush=True)
        res: dict[int, list[float]] = {min(sizes): [], max(sizes): []}
        dom = 41
        for i in range(args.repeats):
            for size in res:
                r = run(args.scenario, args.trials, Path(tmp) / f"{i}-{size}", dom, True,
                        "emulated", chunk=size)
                dom = 41 + (dom - 40) % 50
                res[size].append(r["samples_per_s"])
                print(f"chunk {size:8d} run {i + 1}: {r['samples_per_s']:7.1f} samples/s  "
                      f"file {r['mcap_bytes'] / 1e6:.2f} MB", flush=True)
        for size, v in res.items():
            print(f"  chunk limit {size}: median {statistics.median(v):.1f} samples/s")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="paper-hexagon6")
    ap.add_argument("--trials", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--links", choices=("emulated", "direct", "both"), default="both")
    ap.add_argument("--chunks", type=int, nargs="*", metavar="BYTES",
                    help="measure chunk sizes instead (default 16384 65536 262144 1048576)")
    args = ap.parse_args()
    if args.chunks is not None:
        return bench_chunks(args)
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
