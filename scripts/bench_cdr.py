#!/usr/bin/env python3
"""What packing a recorded trajectory costs: the batch simulator's numpy CDR packer
(formation_ilc.recordings.cdr) against building the message and serialising it with rclpy
(what the stack's nodes do) or with rosbags (a ROS-free serialiser).

Prints microseconds per nav_msgs/msg/Path of S poses (a whole-trial trajectory: one per
robot and trial, measured and true) and per small message, the median of ``--repeats``
timings, and how many times faster the packer is. Checks first that the three give bytes
that decode alike.

Usage: python scripts/bench_cdr.py [--samples 141] [--repeats 7]
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import numpy as np


def per_call(fns: dict[str, Callable[[], object]], repeats: int) -> dict[str, float]:
    """Median over ``repeats`` of the seconds one call of each function takes; the
    functions take turns within each repeat, so that a drift of the machine's load hits
    them alike (each timing runs about 0.1 s)."""
    counts = {}
    for name, fn in fns.items():
        n = 1
        while True:
            t0 = time.perf_counter()
            for _ in range(n):
                fn()
            if time.perf_counter() - t0 > 0.1:
                break
            n *= 2
        counts[name] = n
    times: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            for _ in range(counts[name]):
                fn()
            times[name].append((time.perf_counter() - t0) / counts[name])
    return {name: statistics.median(t) for name, t in times.items()}


def rosbags_path(store: object, eta: np.ndarray, stamps: np.ndarray, frame: str) -> object:
    """A rosbags nav_msgs/msg/Path of planar outputs, as ms.trajectory_to_path builds it."""
    t = store.types  # type: ignore[attr-defined]
    Time, Header = t["builtin_interfaces/msg/Time"], t["std_msgs/msg/Header"]
    Point, Quat = t["geometry_msgs/msg/Point"], t["geometry_msgs/msg/Quaternion"]
    Pose, PoseStamped = t["geometry_msgs/msg/Pose"], t["geometry_msgs/msg/PoseStamped"]

    def stamp(ns: int) -> object:
        sec, nsec = divmod(int(ns), 1_000_000_000)
        return Time(sec=sec, nanosec=nsec)

    poses = [PoseStamped(header=Header(stamp=stamp(s), frame_id=frame),
                         pose=Pose(position=Point(x=float(e[0]), y=float(e[1]), z=0.0),
                                   orientation=Quat(x=0.0, y=0.0, z=float(np.sin(e[2] / 2)),
                                                    w=float(np.cos(e[2] / 2)))))
             for e, s in zip(eta, stamps, strict=True)]
    return t["nav_msgs/msg/Path"](header=Header(stamp=stamp(stamps[-1]), frame_id=frame),
                                  poses=poses)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--samples", type=int, default=141, help="poses per path (T+1)")
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()

    from nav_msgs.msg import Path
    from rclpy.serialization import deserialize_message, serialize_message
    from rosbags.typesys import Stores, get_typestore

    import msgs_schema as ms
    from formation_ilc.recordings import cdr

    store = get_typestore(Stores.ROS2_JAZZY)
    rng = np.random.default_rng(0)
    eta = rng.normal(size=(args.samples, 3))
    stamps = (np.arange(args.samples) + 7) * 200_000_000
    frame = ms.WORLD_FRAME

    ours = cdr.encode_path(eta, stamps, frame, int(stamps[-1]))
    theirs = bytes(serialize_message(ms.trajectory_to_path(eta, stamps.tolist(), frame)))
    rb = bytes(store.serialize_cdr(rosbags_path(store, eta, stamps, frame), "nav_msgs/msg/Path"))
    assert len(ours) == len(theirs) == len(rb)
    assert deserialize_message(ours, Path) == deserialize_message(theirs, Path) == \
        deserialize_message(rb, Path)

    t = per_call({
        "packer": lambda: cdr.encode_path(eta, stamps, frame, int(stamps[-1])),
        "rclpy": lambda: serialize_message(ms.trajectory_to_path(eta, stamps.tolist(), frame)),
        "rosbags": lambda: store.serialize_cdr(rosbags_path(store, eta, stamps, frame),
                                               "nav_msgs/msg/Path"),
    }, args.repeats)
    print(f"nav_msgs/msg/Path of {args.samples} poses ({len(ours)} bytes), per message:")
    print(f"  numpy packer (cdr.encode_path)     {t['packer'] * 1e6:9.1f} us")
    print(f"  rclpy: build + serialize_message   {t['rclpy'] * 1e6:9.1f} us  "
          f"({t['rclpy'] / t['packer']:.0f}x the packer)")
    print(f"  rosbags: build + serialize_cdr     {t['rosbags'] * 1e6:9.1f} us  "
          f"({t['rosbags'] / t['packer']:.0f}x the packer)")

    pose = eta[0]
    Twist = store.types["geometry_msgs/msg/Twist"]
    Vector3 = store.types["geometry_msgs/msg/Vector3"]
    small = per_call({
        "pose": lambda: cdr.encode_pose_stamped(pose, 42, frame),
        "pose_rclpy": lambda: serialize_message(ms.pose_to_msg(tuple(pose), 42, frame)),
        "twist": lambda: cdr.encode_twist(0.5, -1.0),
        "twist_rosbags": lambda: store.serialize_cdr(
            Twist(linear=Vector3(x=0.5, y=0.0, z=0.0), angular=Vector3(x=0.0, y=0.0, z=-1.0)),
            "geometry_msgs/msg/Twist"),
    }, args.repeats)
    print("small messages, per message:")
    print(f"  PoseStamped: packer {small['pose'] * 1e6:.1f} us, "
          f"rclpy {small['pose_rclpy'] * 1e6:.1f} us")
    print(f"  Twist: packer {small['twist'] * 1e6:.1f} us, "
          f"rosbags {small['twist_rosbags'] * 1e6:.1f} us")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
