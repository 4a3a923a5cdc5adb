"""``launch --hosts netns``: a plan's execution with each robot process on a host of its own.

The robots' processes run in network namespaces of their own, joined by veth links to a
hub namespace (leader, simulator, the launcher itself), DDS over UDP with unicast
discovery, the links between robots faulted as asked (docs/lossy-links.md). This wraps the
execution of a ``RunPlan`` (``formation_ilc.plan.specs``): the namespaces, rules and
delayers are set up around it and removed whatever happens, and summary.json gets what the
delayers did. No ROS here.
"""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Callable
from typing import Any

from formation_ilc.core.names import robot_name
from formation_ilc.plan.specs import NodeSpec, RunPlan

__all__ = ["run_on_hosts"]

#: runs a plan with a placement of its processes (``launch.execute``); the exit status
Execute = Callable[[RunPlan, Callable[[NodeSpec], list[str]]], int]


def run_on_hosts(plan: RunPlan, execute: Execute) -> int:
    """``execute(plan, place)`` inside the hub namespace, each robot process placed in its
    own namespace; the namespaces are removed whatever happens. The exit status."""
    from formation_ilc.system import netns

    assert plan.hosts is not None
    orphans = netns.remove_orphans()
    if orphans:
        print(f"removed {len(orphans)} network namespaces of dead launchers", flush=True)
    faults, profile = plan.hosts.faults, plan.hosts.profile
    hosts = netns.Hosts(plan.scenario.n, faults, seed=plan.hosts.seed,
                        log_dir=plan.out / "hosts")

    def place(spec: NodeSpec) -> list[str]:
        if spec.host is None:
            return spec.command
        return hosts.exec_argv(hosts.robot_ns(spec.host), spec.command)

    how = ("through the discovery server in the hub" if plan.discovery == "server"
           else "by unicast to every host")
    saved = dict(os.environ)
    status = 1
    try:
        with hosts:
            os.environ.update(hosts.ros_env(server=plan.discovery == "server"))
            os.environ.pop("FASTRTPS_DEFAULT_PROFILES_FILE", None)
            if plan.hosts.profile_file is not None:
                os.environ["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(plan.hosts.profile_file)
            print(f"hosts: robot i in network namespace {hosts.robot_ns(1)[:-1]}i "
                  f"({netns.SUBNET}.{netns.ROBOT_HOST0}+i), the rest in {hosts.hub} "
                  f"({hosts.hub_address}); links between robots: {faults.describe()}; "
                  f"Fast DDS profile {profile}; discovery {how}", flush=True)
            with hosts.entered_hub():
                status = execute(plan, place)
            stats = hosts.stop_delayers()
    except netns.NetnsError as exc:
        print(f"error: --hosts netns: {exc}", file=sys.stderr)
        return 1
    finally:
        os.environ.clear()
        os.environ.update(saved)
    _report(plan, hosts, stats)
    return status


def _report(plan: RunPlan, hosts: Any, stats: dict[int, dict[str, Any]]) -> None:
    """Print what each robot's delayer did, and add it to summary.json (``hosts``)."""
    from formation_ilc.system import netns

    assert plan.hosts is not None
    report: dict[str, Any] = {"namespaces": hosts.namespaces(), "hub": hosts.hub_address,
                              "faults": vars(plan.hosts.faults),
                              "dds_profile": plan.hosts.profile,
                              "delayers": {robot_name(i): s for i, s in stats.items()}}
    for robot, s in report["delayers"].items():
        lo, p50, p99, hi = netns.hold_quantiles(s.get("hold_ms", {}))
        n = s.get("packets", 0)
        print(f"{robot} -> other robots: {n} packets, {s.get('dropped', 0)} dropped "
              f"({100 * s.get('dropped', 0) / max(n, 1):.1f} %), held {lo:.0f} / {p50:.0f} / "
              f"{p99:.0f} / {hi:.0f} ms (min / p50 / p99 / max)")
    path = plan.out / "summary.json"
    if path.exists():
        summary = json.loads(path.read_text())
        summary["hosts"] = report
        path.write_text(json.dumps(summary, indent=2) + "\n")
