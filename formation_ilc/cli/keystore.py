"""``formation-ilc keystore create DIR SCENARIO``: an SROS2 keystore for a formation.

Makes (or brings up to date) a CA, the governance (authenticated participants only,
discovery and data encrypted) and one enclave per node of the formation, each with
least-privilege permissions derived from the scenario's graph
(``formation_ilc.config.enclaves``): robot i publishes only its own topics and reads its
own pose, its in-neighbours' shared poses and trajectories and the leader's topics it
needs; the plant publishes the poses and reads the ``cmd_vel``; the recorder and the
monitor read. Run it again after changing the graph (a robot added): it keeps every valid
certificate and re-signs only the permissions that changed. ``launch --secure DIR`` runs
every node in its enclave. docs/security.md: threat model, deployment to real robots.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from formation_ilc.cli.options import OptionError, int_range
from formation_ilc.config.enclaves import DriverTopics, Grant, TopicNames, formation_grants

__all__ = ["add_parser", "run", "topic_names", "clock_topic", "grants_for"]

DEFAULT_DRIVER_NS = "/pioneer_{i}"


def clock_topic(namespace: str) -> str:
    """Where the formation's ``/clock`` is: the launcher remaps it into any namespace but
    the default one (``launch.ros_args``)."""
    import msgs_schema as ms

    return ms.CLOCK if namespace == ms.NAMESPACE else f"{namespace.rstrip('/')}{ms.CLOCK}"


def topic_names(namespace: str) -> TopicNames:
    """The schema's topic names (``msgs_schema``, which imports ROS) for the pure grants."""
    import msgs_schema as ms

    return TopicNames(
        config=ms.CONFIG, reference=ms.REFERENCE, trial_events=ms.TRIAL_EVENTS,
        ready=ms.READY, diagnostics=ms.DIAGNOSTICS, clock=clock_topic(namespace),
        pose=ms.pose_topic, cmd_vel=ms.cmd_vel_topic, shared_pose=ms.shared_pose_topic,
        link=ms.link_topic, trajectory=ms.trajectory_topic,
        true_trajectory=ms.true_trajectory_topic,
        recorded=lambda n: [clock_topic(namespace) if t == ms.CLOCK else t
                            for t, _, _ in ms.topic_table(n)],
        leader=ms.LEADER, view=lambda n: [t for t, _, _ in ms.view_topic_table(n)],
        preview=ms.PREVIEW, team_poses=ms.TEAM_POSES)


def grants_for(scenario: Any, namespace: str, *, plant: str = "sim", driver: str = "rosaria",
               driver_ns: str = DEFAULT_DRIVER_NS) -> dict[str, Grant]:
    """Every node's grant for ``scenario`` (a loaded Scenario) in ``namespace``."""
    import msgs_schema as ms

    pioneer = None
    if plant == "pioneer":
        spec = ms.DRIVERS[driver]
        pioneer = DriverTopics(driver_ns, spec.cmd, spec.odom, spec.motors, spec.motors_kind)
    return formation_grants(scenario.graph.adjacency, scenario.graph.leader,
                            topic_names(namespace), namespace, pioneer=pioneer)


def _namespace(value: str) -> str:
    if not value.startswith("/") or "//" in value or value != value.strip():
        raise argparse.ArgumentTypeError(f"{value!r}: an absolute ROS namespace like /team2")
    return value.rstrip("/") or "/"


def add_parser(sub: Any) -> None:
    """Register ``keystore`` (and ``keystore create``) on the CLI's subparsers."""
    p = sub.add_parser("keystore", help="SROS2 keystore for a secure formation",
                       description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    ks = p.add_subparsers(dest="keystore_command", metavar="ACTION", required=True)
    c = ks.add_parser("create", help="make or update a keystore for a scenario's formation",
                      description="Make DIR (or bring it up to date): CA, governance, one "
                                  "enclave per node with permissions from SCENARIO's graph.")
    c.add_argument("keystore", type=Path, metavar="DIR")
    c.add_argument("scenario", metavar="SCENARIO",
                   help="built-in scenario name or YAML file: its graph sets the permissions")
    c.add_argument("--namespace", type=_namespace, default=None, metavar="NS",
                   help="the formation's ROS namespace, as given to launch (default "
                        "/formation)")
    c.add_argument("--days", type=int_range(1, 36500), default=365, metavar="D",
                   help="validity of new enclave certificates and permissions (default 365)")
    c.add_argument("--plant", choices=("sim", "pioneer"), default="sim",
                   help="sim (default): the kinematic simulator drives the robots; pioneer: "
                        "one bridge and one driver enclave per robot (launch --plant pioneer)")
    c.add_argument("--driver", choices=("rosaria", "p2os2", "ros2aria"), default="rosaria",
                   help="with --plant pioneer: the robots' driver (default rosaria)")
    c.add_argument("--driver-ns", default=DEFAULT_DRIVER_NS, metavar="PATTERN",
                   help="with --plant pioneer: robot i's driver namespace (default "
                        "/pioneer_{i})")


def run(args: argparse.Namespace) -> int:
    """``keystore create``: exit 0, or 2 with one line on a bad scenario or keystore."""
    import msgs_schema as ms
    from formation_ilc.config.scenario import load_scenario
    from formation_ilc.store.keystore import KeystoreError, create

    sc = load_scenario(args.scenario)
    namespace = args.namespace or ms.NAMESPACE
    if args.plant == "pioneer" and "{i}" not in args.driver_ns:
        raise OptionError(f"--driver-ns {args.driver_ns!r}: needs {{i}} (one namespace per "
                          f"robot)")
    grants = grants_for(sc, namespace, plant=args.plant, driver=args.driver,
                        driver_ns=args.driver_ns)
    try:
        done = create(args.keystore, grants, days=args.days)
    except KeystoreError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for line in done.lines():
        print(f"{args.keystore}: {line}")
    print(f"{args.keystore}: {len(grants)} enclaves for {sc.name} ({sc.n} robots) in "
          f"{namespace}; run it with `formation-ilc launch {args.scenario} --secure "
          f"{args.keystore}`")
    return 0
