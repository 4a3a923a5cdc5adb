#!/usr/bin/env python3
"""Latency of one robot-to-robot topic over a lossy link: Fast DDS defaults against the
package's lossy-links profile (a 50 ms writer heartbeat).

Two robot namespaces (formation_ilc.system.netns.Hosts, root needed), a delayer on robot 1's
outgoing link (default 100 +- 50 ms, 5 % loss, as the realtime test), robot 1 publishing
PoseStamped at 20 Hz (dT = 0.05 s) with the QoS of the shared poses (msgs_schema.SAMPLE_QOS:
reliable, keep last 64), robot 2 timing each arrival against the stamp (both namespaces
read the same clock). Prints, per setting, messages sent and received and the one-way
latency p50 / p90 / p99 / max; `--json FILE` writes them.

Usage: sudo python scripts/bench_lossy_links.py [--seconds 60] [--delay-ms 100]
                                                [--jitter-ms 50] [--loss 0.05]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROLE_CODE = r"""
import json, sys, time
import rclpy
from geometry_msgs.msg import PoseStamped
import msgs_schema as ms

role, seconds, out = sys.argv[1], float(sys.argv[2]), sys.argv[3]
rclpy.init()
node = rclpy.create_node("bench_" + role)
if role == "pub":
    pub = node.create_publisher(PoseStamped, "bench/pose", ms.SAMPLE_QOS)
    deadline = time.monotonic() + 60
    while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    time.sleep(1.0)  # the reader's side of the match, too
    msg = PoseStamped()
    n = int(seconds * 20)
    t0 = time.monotonic()
    for k in range(n):
        while time.monotonic() < t0 + 0.05 * k:
            rclpy.spin_once(node, timeout_sec=max(0.0, t0 + 0.05 * k - time.monotonic()))
        now = time.time_ns()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(now, 10**9)
        msg.pose.position.x = float(k)
        pub.publish(msg)
    end = time.monotonic() + 8.0  # keep the writer alive for repairs
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    json.dump({"sent": n}, open(out, "w"))
else:
    lat = []
    last = [time.monotonic()]
    def on(m):
        lat.append((time.time_ns() - (m.header.stamp.sec * 10**9 + m.header.stamp.nanosec)) / 1e6)
        last[0] = time.monotonic()
    node.create_subscription(PoseStamped, "bench/pose", on, ms.SAMPLE_QOS)
    end = time.monotonic() + seconds + 90
    while time.monotonic() < end and not (lat and time.monotonic() - last[0] > 10.0):
        rclpy.spin_once(node, timeout_sec=0.05)
    json.dump({"latency_ms": lat}, open(out, "w"))
node.destroy_node()
rclpy.try_shutdown()
"""


def pct(xs: list[float], q: float) -> float:
    s = sorted(xs)
    return s[min(len(s) - 1, int(q * len(s)))] if s else float("nan")


def one(profile: bool, args: argparse.Namespace, tmp: Path, domain: int) -> dict:
    from formation_ilc.system.netns import Hosts, LinkFaults, lossy_profile

    faults = LinkFaults(args.delay_ms, args.jitter_ms, args.loss)
    with Hosts(2, faults, seed=args.seed, log_dir=tmp / "hosts") as hosts:
        env = dict(os.environ, **hosts.ros_env(), ROS_DOMAIN_ID=str(domain))
        env.pop("FASTRTPS_DEFAULT_PROFILES_FILE", None)
        if profile:
            env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(lossy_profile())
        procs = []
        for i, role in ((2, "sub"), (1, "pub")):
            argv = [sys.executable, "-c", ROLE_CODE, role, str(args.seconds),
                    str(tmp / f"{role}.json")]
            procs.append(subprocess.Popen(hosts.exec_argv(hosts.robot_ns(i), argv), env=env))
        for p in procs:
            p.wait(timeout=args.seconds + 200)
        stats = hosts.stop_delayers()[1]
    lat = json.loads((tmp / "sub.json").read_text())["latency_ms"]
    sent = json.loads((tmp / "pub.json").read_text())["sent"]
    return {"profile": "lossy-links (heartbeat 50 ms)" if profile else "Fast DDS default",
            "sent": sent, "received": len(lat), "p50_ms": pct(lat, 0.5),
            "p90_ms": pct(lat, 0.9), "p99_ms": pct(lat, 0.99), "max_ms": max(lat, default=0),
            "packets": stats.get("packets"), "dropped": stats.get("dropped")}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--delay-ms", type=float, default=100.0)
    ap.add_argument("--jitter-ms", type=float, default=50.0)
    ap.add_argument("--loss", type=float, default=0.05)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    from formation_ilc.system.netns import support_problem

    problem = support_problem()
    if problem:
        print(f"error: {problem}", file=sys.stderr)
        return 2
    rows = []
    for k, profile in enumerate((False, True)):
        with tempfile.TemporaryDirectory() as d:
            row = one(profile, args, Path(d), 90 + k)
        rows.append(row)
        print(f"{row['profile']:32s} sent {row['sent']} received {row['received']}  "
              f"latency p50 {row['p50_ms']:.0f} p90 {row['p90_ms']:.0f} p99 "
              f"{row['p99_ms']:.0f} max {row['max_ms']:.0f} ms  (delayer: {row['packets']} "
              f"packets, {row['dropped']} dropped)", flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
