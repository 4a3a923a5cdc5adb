"""``formation-ilc keystore create DIR SCENARIO``: an SROS2 keystore for a formation.

Makes (or brings up to date) a CA, the governance (authenticated participants only,
discovery and data encrypted) and one enclave per node of the formation, each with
least-privilege permissions: its member's topics in the roster
(``formation_ilc.config.roster``), derived from the scenario's graph. Robot i publishes
only its own topics and reads its own pose, its in-neighbours' shared poses and
trajectories and the leader's topics it needs; the plant publishes the poses and reads the
``cmd_vel`` (the simulator, the physics plant, or each robot's bridge and its driver); the
recorder and the monitor read. Run it again after changing the graph (a robot added): it
keeps every valid certificate and re-signs only the permissions that changed. ``launch
--secure DIR`` runs every node in its enclave. docs/security.md: threat model, deployment
to real robots.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from formation_ilc.cli.options import OptionError, int_range, out_dir_arg
from formation_ilc.config.enclaves import Grant
from formation_ilc.config.plants import SECURE_PLANTS, plant
from formation_ilc.config.roster import DRIVER_NS, Lineup, roster
from formation_ilc.core.names import NAMESPACE, driver_ns_problem

__all__ = ["add_parser", "run", "grants_for"]


def grants_for(scenario: Any, namespace: str, *, plant: str = "sim", driver: str = "rosaria",
               driver_ns: str | None = None, base: str | None = None,
               physics_bases: bool = False) -> dict[str, Grant]:
    """Every enclave's grant for ``scenario`` (a loaded Scenario) in ``namespace``: every
    member a run of its formation on ``plant`` may start (``Lineup.for_keystore``)."""
    lineup = Lineup.of(scenario.graph, plant=plant, driver=driver, driver_ns=driver_ns,
                       base=base, physics_bases=physics_bases)
    return roster(lineup.for_keystore()).grants(namespace)


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
    c.add_argument("keystore", type=out_dir_arg, metavar="DIR")
    c.add_argument("scenario", metavar="SCENARIO",
                   help="built-in scenario name or YAML file: its graph sets the permissions; "
                        "or a run file (formation-ilc run-file): its scenario, plant, "
                        "driver and namespace, and with its hosts: one bundle per host in "
                        "DIR/bundles/HOST holding only that host's enclaves")
    c.add_argument("--namespace", type=_namespace, default=None, metavar="NS",
                   help="the formation's ROS namespace, as given to launch (default "
                        "/formation)")
    c.add_argument("--days", type=int_range(1, 36500), default=365, metavar="D",
                   help="validity of new enclave certificates and permissions (default 365)")
    c.add_argument("--plant", choices=SECURE_PLANTS, default=SECURE_PLANTS[0],
                   help="the plant of the runs the keystore serves, as given to launch: sim "
                        "(default): the kinematic simulator drives the robots; physics: the "
                        "physics plant; pioneer: one bridge and one driver enclave per "
                        "robot; base: one bridge per robot and a driver enclave per base "
                        "(with --physics-bases: one enclave for the physics bases instead)")
    from formation_ilc.cli.options import argument_of
    from formation_ilc.config.option_table import option

    for name in ("driver", "driver_ns", "base", "physics_bases"):  # as given to launch
        flags, kw = argument_of(option(name))
        if name == "driver_ns":  # none given: each plant's usual pattern
            kw["default"] = None
        c.add_argument(*flags, **kw)


def run(args: argparse.Namespace) -> int:
    """``keystore create``: exit 0, or 2 with one line on a bad scenario or keystore."""
    from formation_ilc.cli.runfile import is_run_file
    from formation_ilc.config.scenario import load_scenario

    if is_run_file(args.scenario):
        return _run_file_keystore(args)
    sc = load_scenario(args.scenario)
    namespace = args.namespace or NAMESPACE
    row = plant(args.plant)
    if args.physics_bases and row.driver != "base":
        raise OptionError("--physics-bases goes with --plant base")
    driver_ns = args.driver_ns or DRIVER_NS.get(row.driver or "")
    if row.driver is not None and driver_ns is not None:
        why = driver_ns_problem(driver_ns)
        if why is not None:  # before, permissions were written for an invalid name
            raise OptionError(f"argument --driver-ns: {driver_ns!r}: {why}")
    grants = grants_for(sc, namespace, plant=args.plant, driver=args.driver,
                        driver_ns=driver_ns,
                        base=args.base if row.driver == "base" else None,
                        physics_bases=args.physics_bases)
    if not _created(args, grants, sc, namespace):
        return 2
    print(f"{args.keystore}: run it with `formation-ilc launch {args.scenario} --secure "
          f"{args.keystore}`")
    return 0


def _created(args: argparse.Namespace, grants: dict[str, Grant], sc: Any,
             namespace: str) -> bool:
    """Make or update the keystore ``args.keystore`` for ``grants``, saying what changed;
    False (said in one line) when it cannot be."""
    from formation_ilc.store.keystore import KeystoreError, create

    try:
        done = create(args.keystore, grants, days=args.days)
    except KeystoreError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return False
    except OSError as exc:  # a folder that cannot be made or written: the user's path
        from formation_ilc.system.exits import is_disk_full

        if is_disk_full(exc):
            raise  # the command's disk-full status and line
        print(f"error: {args.keystore}: cannot make the keystore there: "
              f"{exc.strerror or exc}", file=sys.stderr)
        return False
    for line in done.lines():
        print(f"{args.keystore}: {line}")
    print(f"{args.keystore}: {len(grants)} enclaves for {sc.name} ({sc.n} robots) in "
          f"{namespace}")
    return True


def _run_file_keystore(args: argparse.Namespace) -> int:
    """``keystore create DIR RUN.yaml``: the keystore of the run a run file plans (its
    members' enclaves and the launcher's), and with its ``hosts:`` one bundle per host in
    DIR/bundles/HOST: the CA's certificate, the governance and that host's enclaves only
    (the ground station's with the launcher's monitor), never the CA's private key."""
    from pathlib import Path

    from formation_ilc.cli.runfile import launch_options
    from formation_ilc.core.names import MONITOR_NODE
    from formation_ilc.plan.build import decide, unmade_folder
    from formation_ilc.plan.machine import Machine
    from formation_ilc.plan.specs import NoRun
    from formation_ilc.store.keystore import bundle

    given = [k for k in ("namespace", "driver_ns", "physics_bases") if getattr(args, k)]
    if given or args.plant != SECURE_PLANTS[0] or args.base != "turtlebot4":
        raise OptionError("keystore create DIR RUN.yaml: the run file says the plant, the "
                          "driver and the namespace (give only --days)")
    opts = launch_options(argparse.Namespace(scenario=args.scenario))
    machine = Machine.probe()
    try:  # planned, not prepared: no folder made
        plan = decide(opts.with_fields({"out": unmade_folder(machine), "secure": None}),
                      machine)
    except NoRun as stop:
        return stop.report()
    grants = roster(plan.roster.lineup.for_keystore()).grants(plan.namespace)
    if not _created(args, grants, plan.scenario, plan.namespace):
        return 2
    from formation_ilc.config.enclaves import enclave_path

    for host, members in plan.host_members:
        names = {plan.roster.enclave_of(m) for m in members if m != MONITOR_NODE}
        if MONITOR_NODE in members:
            names.add(MONITOR_NODE)
        held = bundle(args.keystore, Path(args.keystore) / "bundles" / host,
                      [enclave_path(plan.namespace, n) for n in names])
        print(f"{args.keystore}/bundles/{host}: {', '.join(held)} (copy it to host {host} "
              f"as the run file's security.keystore)")
    return 0
